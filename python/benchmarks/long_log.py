"""Whether a long robot log replays in bounded memory: `twinbots replay` reads an MCAP log a
chunk at a time as the twin steps along it, so its memory should not grow with the log.

Records a minute of the UR5e's twin (`twinbots record`), tiles it, with its times shifted, into
one MCAP log of `--gigabytes` (joint states at 250 Hz and commands at 125 Hz, as `record` writes
them: about 4.8 hours of robot time for 2 GB), then replays the minute and the long log with
`twinbots replay` and prints each one's peak resident memory (the kernel's `ru_maxrss`), its
resident memory sampled every 5 s, and the wall time.

    python benchmarks/long_log.py [--gigabytes 2] [--dir DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import tempfile
import threading
import time

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer


def binary() -> str:
    return os.environ.get("TWINBOTS_BIN", "twinbots")


def tile(segment: str, out: str, target_bytes: int) -> int:
    """Writes `segment`'s messages again and again, times shifted by its span each round, until
    `out` holds `target_bytes`; returns the rounds written."""
    with open(segment, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        messages = [(channel.id, message.log_time, message.data) for _, channel, message in reader.iter_messages()]
    span = messages[-1][1] - messages[0][1] + 4_000_000
    rounds = 0
    with open(out, "wb") as f:
        # Uncompressed chunks: what twinbots reads (compressed logs are refused, docs/logs.md).
        writer = Writer(f, compression=CompressionType.NONE)
        writer.start(profile="ros2")
        schema_ids = {
            sid: writer.register_schema(s.name, s.encoding, s.data) for sid, s in summary.schemas.items()
        }
        channel_ids = {
            cid: writer.register_channel(c.topic, c.message_encoding, schema_ids.get(c.schema_id, 0), dict(c.metadata))
            for cid, c in summary.channels.items()
        }
        topics = {cid: c.topic for cid, c in summary.channels.items()}
        for name, data in metadata:
            writer.add_metadata(name, data)
        while f.tell() < target_bytes:
            shift = rounds * span
            for channel, log_time, data in messages:
                if topics[channel] == "/twinbots/joint_commands":
                    command = json.loads(data)
                    command["time"] += shift * 1e-9
                    data = json.dumps(command).encode()
                else:
                    # CDR: a 4-byte encapsulation header, then the header's stamp (sec, nanosec).
                    sec, nanosec = struct.unpack_from("<iI", data, 4)
                    stamp = sec * 1_000_000_000 + nanosec + shift
                    data = data[:4] + struct.pack("<iI", stamp // 1_000_000_000, stamp % 1_000_000_000) + data[12:]
                writer.add_message(channel_ids[channel], log_time + shift, data, log_time + shift)
            rounds += 1
        writer.finish()
    return rounds


def replay(log: str, out: str) -> dict:
    """Runs `twinbots replay ur5e LOG`, sampling its resident memory every 5 s."""
    started = time.monotonic()
    process = subprocess.Popen([binary(), "replay", "ur5e", log, "--out", out], stdout=subprocess.DEVNULL)
    samples: list[int] = []

    def sample() -> None:
        while process.poll() is None:
            try:
                with open(f"/proc/{process.pid}/status") as status:
                    samples.extend(int(line.split()[1]) for line in status if line.startswith("VmRSS:"))
                samples[:] = [s for s in samples if s > 0]
            except OSError:
                return
            time.sleep(5)

    threading.Thread(target=sample, daemon=True).start()
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise RuntimeError(f"replay of {log} failed ({process.returncode})")
    with open(os.path.join(out, "replay.json")) as f:
        seconds = json.load(f)["seconds"]
    return {
        "log_bytes": os.path.getsize(log),
        "log_seconds": seconds,
        "peak_rss_mib": usage.ru_maxrss / 1024,
        "rss_mib_every_5s": [round(s / 1024, 1) for s in samples],
        "wall_s": time.monotonic() - started,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gigabytes", type=float, default=2.0)
    parser.add_argument("--dir", default=None, help="where the logs go (default: a temporary folder)")
    args = parser.parse_args()
    work = args.dir or tempfile.mkdtemp(prefix="twinbots-long-log-")
    os.makedirs(work, exist_ok=True)
    segment, long = os.path.join(work, "minute.mcap"), os.path.join(work, "long.mcap")
    subprocess.run([binary(), "record", "ur5e", "--seconds", "60", "--out", segment], check=True,
                   stdout=subprocess.DEVNULL)
    started = time.monotonic()
    rounds = tile(segment, long, int(args.gigabytes * 1e9))
    print(f"wrote {long}: {os.path.getsize(long) / 1e9:.2f} GB, {rounds} minutes tiled, "
          f"{time.monotonic() - started:.0f} s", flush=True)
    for name, log in [("a minute", segment), ("the long log", long)]:
        result = replay(log, log + ".replay")
        trace = result.pop("rss_mib_every_5s")
        print(f"{name}: {json.dumps(result)}", flush=True)
        if trace:
            print(f"  RSS (MiB) every 5 s: first {trace[0]}, largest {max(trace)}, last {trace[-1]} "
                  f"({len(trace)} samples)", flush=True)


if __name__ == "__main__":
    main()
