"""Whether a twinbots server grows under hostile peers: the RobotServer (`twinbots serve`), the UR
controller stand-in (`twinbots ur-sim`, RTDE) and the live view (`twinbots view --live
--no-window`, Foxglove's WebSocket protocol), each hammered for `--seconds` by clients written
here that do what a broken or hostile peer does, round after round:

- random bytes, then close;
- a frame header promising more than the server takes (4 GiB; RTDE's 65,535), half of it, close;
- connections that say nothing, up to 40 held at once, each dropped after a few seconds;
- a valid opening (a hello; RTDE's protocol request; a WebSocket upgrade), then garbage;
- connect and close at once.

Each server's resident memory (`VmRSS`) is sampled every 5 s. Prints, per server, its RSS after
the first minute, the largest, the last, the connections made and whether it still answers a
well-formed opening at the end.

    python benchmarks/hostile_rss.py [--seconds 600]
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import random
import socket
import struct
import subprocess
import tempfile
import threading
import time


def binary() -> str:
    return os.environ.get("TWINBOTS_BIN", "twinbots")


def rss_kib(pid: int) -> int:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def start(args: list[str], marker: str) -> tuple[subprocess.Popen, tuple[str, int]]:
    """Starts a server and reads its address from the first output line containing `marker`."""
    process = subprocess.Popen([binary(), *args], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    for line in process.stdout:
        if marker in line:
            address = line.split(marker, 1)[1].split()[0].removeprefix("ws://")
            host, port = address.rsplit(":", 1)
            threading.Thread(target=process.stdout.read, daemon=True).start()
            return process, (host, int(port))
    raise RuntimeError(f"{args[0]} did not start")


def hello() -> bytes:
    payload = json.dumps({"type": "hello", "version": 2, "robot": "cartpole",
                          "observation_space": {"Box": {"low": [-1e9] * 4, "high": [1e9] * 4}},
                          "action_space": {"Discrete": 2}, "token": None}).encode()
    return struct.pack("<I", len(payload)) + payload


def rtde_version() -> bytes:
    return struct.pack(">HBH", 5, ord("V"), 2)


def upgrade() -> bytes:
    key = base64.b64encode(os.urandom(16)).decode()
    return (f"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            f"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n").encode()


KINDS = {
    "serve": {"opening": hello, "huge": lambda: struct.pack("<I", 0xFFFF_FFFF) + b"{" * 1000},
    "ur-sim": {"opening": rtde_version, "huge": lambda: struct.pack(">HB", 65535, ord("U")) + b"\0" * 30000},
    "live": {"opening": upgrade, "huge": lambda: upgrade() + bytes([0x82, 0x7F]) + struct.pack(">Q", 1 << 40)},
}


def attack(kind: str, address: tuple[str, int], until: float, counts: dict, seed: int) -> None:
    draw = random.Random(seed)
    held: list[tuple[float, socket.socket]] = []
    build = KINDS[kind]
    while time.monotonic() < until:
        round_kind = draw.randrange(5)
        try:
            sock = socket.create_connection(address, timeout=2)
            counts["connections"] += 1
            if round_kind == 0:
                sock.sendall(os.urandom(draw.randint(1, 4096)))
            elif round_kind == 1:
                frame = build["huge"]()
                sock.sendall(frame[: max(1, len(frame) // 2)])
            elif round_kind == 2 and len(held) < 40:
                held.append((time.monotonic() + draw.uniform(1, 8), sock))
                sock = None
            elif round_kind == 3:
                sock.sendall(build["opening"]())
                for _ in range(draw.randint(1, 20)):
                    sock.sendall(os.urandom(draw.randint(1, 512)))
                    time.sleep(0.001)
            if sock is not None:
                sock.close()
        except OSError:
            counts["refused"] += 1
        now = time.monotonic()
        for _, s in [h for h in held if h[0] <= now]:
            s.close()
        held = [h for h in held if h[0] > now]
        time.sleep(0.002)
    for _, s in held:
        s.close()


def answers(kind: str, address: tuple[str, int]) -> bool:
    """Whether the server still answers a well-formed opening."""
    try:
        with socket.create_connection(address, timeout=5) as sock:
            sock.sendall(KINDS[kind]["opening"]())
            return len(sock.recv(64)) > 0
    except OSError:
        return False


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        servers = {
            "serve": start(["serve", "cartpole", "--listen", "127.0.0.1:0", "--robots", "1", "--timesteps",
                            "100000000", "--out", f"{tmp}/run", "--handshake-timeout", "2", "--read-timeout",
                            "5"], "listening on "),
            "ur-sim": start(["ur-sim", "--listen", "127.0.0.1:0"], "serving RTDE on "),
            "live": start(["view", "cartpole", "--no-window", "--live", "127.0.0.1:0"], "live view on "),
        }
        until = time.monotonic() + args.seconds
        counts = {kind: {"connections": 0, "refused": 0} for kind in servers}
        threads = [threading.Thread(target=attack, args=(kind, address, until, counts[kind], k), daemon=True)
                   for k, (kind, (_, address)) in enumerate(servers.items())]
        for t in threads:
            t.start()
        samples: dict[str, list[tuple[float, int]]] = {kind: [] for kind in servers}
        began = time.monotonic()
        while time.monotonic() < until:
            for kind, (process, _) in servers.items():
                if process.poll() is None:
                    samples[kind].append((time.monotonic() - began, rss_kib(process.pid)))
            time.sleep(5)
        for t in threads:
            t.join()
        for kind, (process, address) in servers.items():
            alive = process.poll() is None
            series = samples[kind]
            after_minute = next((r for t, r in series if t >= 60), series[-1][1] if series else 0)
            count = counts[kind]
            print(f"{kind}: {args.seconds:.0f} s, {count['connections']} hostile connections "
                  f"({count['refused']} ended by the server mid-send); RSS after 1 min {after_minute / 1024:.1f} MiB, "
                  f"largest "
                  f"{max(r for _, r in series) / 1024:.1f} MiB, last {series[-1][1] / 1024:.1f} MiB; "
                  f"{'running' if alive else 'EXITED'}, answers a well-formed opening: {answers(kind, address)}",
                  flush=True)
            process.kill()
            process.wait()


if __name__ == "__main__":
    main()
