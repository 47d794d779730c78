"""The cart-pole twin trained to the paper's criterion (mean score of the last 100 episodes above
1950) twice in one run: by Stable-Baselines3's PPO through the Python package, as a user of the
WebotsRL stack would, and by `twinbots train cartpole`; prints both wall clocks and their ratio.

    python benchmarks/sb3_vs_twinbots.py [--seed 0] [--timesteps 2000000] [--twinbots PATH]

SB3 runs with the settings of examples/sb3_cartpole.py (RL Zoo's CartPole-v1, 8 envs); twinbots
with its own defaults for the robot. Each side stops at the criterion (or at --timesteps) and
is timed from the start of training to that stop, model and env creation included. The
twinbots CLI is --twinbots, else $TWINBOTS_BIN, else `twinbots` on PATH (cargo build --release
puts it in $CARGO_TARGET_DIR/release). Run it with nothing else on the machine."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "examples"))
from sb3_cartpole import SOLVED, StopWhenSolved  # noqa: E402


def sb3(seed: int, timesteps: int) -> dict:
    import numpy as np
    import torch
    from stable_baselines3 import PPO

    from twinbots.sb3 import make_vec_env

    start = time.perf_counter()
    env = make_vec_env("cartpole", n_envs=8, seed=seed)
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=256, n_epochs=20, gae_lambda=0.8, gamma=0.98,
                learning_rate=1e-3, clip_range=0.2, ent_coef=0.0, seed=seed, device="cpu", verbose=0)
    stop = StopWhenSolved()
    model.learn(total_timesteps=timesteps, callback=stop)
    wall = time.perf_counter() - start
    mean = float(np.mean(stop.scores)) if stop.scores else 0.0
    return {"solved": len(stop.scores) == 100 and mean > SOLVED, "steps": int(model.num_timesteps), "wall_s": wall,
            "mean_last_100": mean, "threads": torch.get_num_threads()}


def twinbots(binary: str, seed: int, timesteps: int) -> dict:
    with tempfile.TemporaryDirectory() as out:
        run = Path(out) / "run"
        start = time.perf_counter()
        done = subprocess.run([binary, "train", "cartpole", "--seed", str(seed), "--timesteps", str(timesteps),
                               "--out", str(run)],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        wall = time.perf_counter() - start
        if done.returncode != 0:
            raise SystemExit(f"twinbots train failed:\n{done.stdout}")
        summary = json.loads((run / "summary.json").read_text())
    return {"solved": summary["solved"], "steps": summary["solved_at_timesteps"] or summary["timesteps"],
            "wall_s": wall, "training_s": summary["wall_clock_s_this_session"],
            "mean_last_100": summary["mean_reward_last_100"]}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timesteps", type=int, default=2_000_000, help="the most steps either side may take")
    parser.add_argument("--twinbots", help="the twinbots CLI")
    args = parser.parse_args()
    binary = args.twinbots or os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")
    if not binary:
        raise SystemExit("no twinbots CLI: pass --twinbots PATH or set TWINBOTS_BIN")

    print(f"twinbots train cartpole (seed {args.seed}) ...", flush=True)
    ours = twinbots(binary, args.seed, args.timesteps)
    print(f"Stable-Baselines3 PPO on twinbots.sb3.make_vec_env('cartpole', n_envs=8) (seed {args.seed}) ...",
          flush=True)
    theirs = sb3(args.seed, args.timesteps)

    def line(name, r):
        state = "solved" if r["solved"] else "NOT solved"
        return (f"{name:<24} {state:<10} {r['steps']:>9} steps {r['wall_s']:>8.1f} s wall   "
                f"last-100 mean {r['mean_last_100']:.1f}")

    print(line("twinbots train", ours) + f"   (training {ours['training_s']:.1f} s of it)")
    print(line("SB3 PPO via twinbots.sb3", theirs) + f"   (torch threads {theirs['threads']})")
    if ours["solved"] and theirs["solved"]:
        print(f"ratio: SB3 takes {theirs['wall_s'] / ours['wall_s']:.1f}x twinbots' wall clock "
              f"({theirs['steps'] / ours['steps']:.2f}x its steps)")


if __name__ == "__main__":
    main()
