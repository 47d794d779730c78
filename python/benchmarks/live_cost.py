"""What a connected live viewer costs training: `twinbots train cartpole` (the README's command,
seed 0: the same steps every time) with `--live` and a client subscribed to every channel of
arena 0 and the transforms, against the same run with no live view, taking turns.

    python benchmarks/live_cost.py [--rounds 3] [--robot cartpole] [--every-step]

By default the live view is paced (a frame per control period of wall time); `--every-step`
serves every control step (`train --live-every-step`).

Prints each run's training wall clock (`summary.json`'s `wall_clock_s_this_session`) and the
medians. The client is the protocol-spec client of `tests/test_live.py` in a thread of its own."""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import tempfile
import threading
from pathlib import Path


def binary() -> str:
    return os.environ.get("TWINBOTS_BIN", "twinbots")


async def subscribe_all(port: int, stop: threading.Event, counts: dict) -> None:
    import websockets

    async with websockets.connect(
        f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"], max_size=1 << 28
    ) as ws:
        subscribed = set()
        while not stop.is_set():
            try:
                frame = await asyncio.wait_for(ws.recv(), 0.5)
            except asyncio.TimeoutError:
                continue
            except websockets.ConnectionClosed:
                return
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "advertise":
                    wanted = [
                        c
                        for c in message["channels"]
                        if c["topic"].startswith(("/arena_0/", "/tf", "/scene", "/episodes"))
                    ]
                    new = [c for c in wanted if c["id"] not in subscribed]
                    subscribed.update(c["id"] for c in new)
                    if new:
                        subs = [{"id": c["id"], "channelId": c["id"]} for c in new]
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            else:
                counts["messages"] = counts.get("messages", 0) + 1


def run(robot: str, live: bool, every_step: bool = False) -> tuple[float, int]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        command = [binary(), "train", robot, "--out", str(out)]
        if live:
            command += ["--live", "127.0.0.1:0"] + (["--live-every-step"] if every_step else [])
        train = subprocess.Popen(command, stdout=subprocess.PIPE, text=True)
        stop, counts, client = threading.Event(), {}, None
        if live:
            port = int(train.stdout.readline().split(":")[2].split()[0])
            client = threading.Thread(target=lambda: asyncio.run(subscribe_all(port, stop, counts)))
            client.start()
        train.communicate()
        stop.set()
        if client:
            client.join()
        summary = json.loads((out / "summary.json").read_text())
        return summary["wall_clock_s_this_session"], counts.get("messages", 0)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--robot", default="cartpole")
    parser.add_argument("--every-step", action="store_true", help="serve every control step")
    args = parser.parse_args()
    without, with_client = [], []
    for k in range(args.rounds):
        for live in [False, True] if k % 2 == 0 else [True, False]:
            wall, messages = run(args.robot, live, args.every_step)
            (with_client if live else without).append(wall)
            print(
                f"round {k}: {'with a client' if live else 'no live view'}: {wall:.2f} s"
                + (f", {messages} messages received" if live else "")
            )
    a, b = statistics.median(without), statistics.median(with_client)
    print(f"median: no live view {a:.2f} s, with a client {b:.2f} s ({100 * (b - a) / a:+.1f} %)")


if __name__ == "__main__":
    main()
