"""What a robot whose readings are wild but plausible does to a served run's observation
statistics (design pattern 3): `twinbots serve cartpole` with PPO's observation normalisation on,
`--honest` robots (`twinbots robot cartpole`, each its own twin) and `--wild` robots written here
from docs/protocol.md that report readings drawn uniformly from 90 % of each value's plausible
range (the welcome's `observation_plausible`: a cart at ±4.5 m, a pole spinning at ±90 rad/s),
reward 1 a step, episodes of 10 to 500 steps. The server refuses nothing of theirs: every value
is plausible.

    python benchmarks/wild_robot.py [--seeds 0 1 2] [--wild 1] [--honest 3] [--timesteps 150000]

Each run's final model is evaluated on the twin (`twinbots eval RUN --episodes 20`): its mean
episode length (1,951 at most) is what the honest robots' training learned. Prints each run, its
model's observation variances (the statistics the wild robot should not have moved) and the
median over seeds."""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
import statistics
import struct
import subprocess
import tempfile
import threading
from pathlib import Path


def binary() -> str:
    return os.environ.get("TWINBOTS_BIN", "twinbots")


def send(sock: socket.socket, message: dict) -> None:
    payload = json.dumps(message).encode()
    sock.sendall(struct.pack("<I", len(payload)) + payload)


def receive(sock: socket.socket) -> dict:
    def exactly(n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("the server closed the connection")
            data += chunk
        return data

    (length,) = struct.unpack("<I", exactly(4))
    return json.loads(exactly(length))


def wild_robot(address: tuple[str, int], seed: int) -> None:
    """Plays until the server says done: uniform readings over 90 % of the plausible box."""
    spaces = json.loads(subprocess.run([binary(), "robots", "--json"], capture_output=True, check=True).stdout)
    task = next(r for r in spaces["robots"] if r["name"] == "cartpole")["tasks"][0]
    hello = {"type": "hello", "version": 2, "robot": "cartpole", "observation_space": task["observation_space"],
             "action_space": task["action_space"], "token": None}
    draw = random.Random(seed)
    try:
        with socket.create_connection(address, timeout=120) as sock:
            send(sock, hello)
            welcome = receive(sock)
            box = welcome["task"]["observation_plausible"]["Box"]
            low, high = box["low"], box["high"]

            def reading() -> list[float]:
                return [0.9 * draw.uniform(lo, hi) for lo, hi in zip(low, high)]

            while True:
                send(sock, {"type": "start", "obs": reading()})
                reply = receive(sock)
                for _ in range(draw.randint(10, 500)):
                    if reply["type"] == "done":
                        return
                    send(sock, {"type": "step", "obs": reading(), "reward": 1.0, "terminated": False,
                                "truncated": False})
                    reply = receive(sock)
                if reply["type"] == "done":
                    return
                send(sock, {"type": "step", "obs": reading(), "reward": 1.0, "terminated": True, "truncated": False})
                if receive(sock)["type"] == "done":
                    return
    except (ConnectionError, OSError):
        return


def observation_variances(model: Path) -> list[float] | None:
    """The final model's observation statistics' variances (`model.json`'s `obs_rms`)."""
    def find(node):
        if isinstance(node, dict):
            if "obs_rms" in node:
                return node["obs_rms"]
            for value in node.values():
                found = find(value)
                if found:
                    return found
        return None

    rms = find(json.loads((model / "model.json").read_text()))
    return rms["var"] if rms else None


def run(seed: int, wild: int, honest: int, timesteps: int, workdir: Path,
        normalise: bool = True) -> tuple[float, list[float] | None]:
    config = workdir / "normalise.toml"
    config.write_text(f"[ppo]\nnormalize_observations = {str(normalise).lower()}\n")
    out = workdir / f"seed{seed}-wild{wild}"
    server = subprocess.Popen(
        [binary(), "serve", "cartpole", "--listen", "127.0.0.1:0", "--robots", str(wild + honest), "--timesteps",
         str(timesteps), "--seed", str(seed), "--config", str(config), "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    line = server.stdout.readline()
    assert line.startswith("listening on "), line
    host, port = line.split()[-1].rsplit(":", 1)
    robots = [subprocess.Popen([binary(), "robot", "cartpole", "--server", f"{host}:{port}", "--seed",
                                str(100 * seed + k)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
              for k in range(honest)]
    threads = [threading.Thread(target=wild_robot, args=((host, int(port)), 1000 * seed + k), daemon=True)
               for k in range(wild)]
    for t in threads:
        t.start()
    server.stdout.read()  # until the run ends
    assert server.wait() == 0, f"serve failed: {out}"
    for r in robots:
        r.wait(timeout=60)
    subprocess.run([binary(), "eval", str(out), "--episodes", "20"], check=True, capture_output=True)
    report = json.loads((out / "eval.json").read_text())
    return float(report["mean_length"]), observation_variances(out / "model")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--wild", type=int, default=1)
    parser.add_argument("--honest", type=int, default=3)
    parser.add_argument("--timesteps", type=int, default=150_000)
    parser.add_argument("--no-normalise", action="store_true", help="PPO without observation normalisation")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        lengths = []
        for seed in args.seeds:
            length, variances = run(seed, args.wild, args.honest, args.timesteps, Path(tmp), not args.no_normalise)
            lengths.append(length)
            shown = ", ".join(f"{v:.3g}" for v in variances) if variances else "none"
            print(f"seed {seed}: {args.honest} honest + {args.wild} wild robots, final model's mean length "
                  f"{length:.1f}; observation variances {shown}", flush=True)
        print(f"median over seeds {args.seeds}: {statistics.median(lengths):.1f}")


if __name__ == "__main__":
    main()
