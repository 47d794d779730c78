"""RLlib on the cart-pole twin: sampled env steps/s with 1 and 2 env runners (8 arenas in all),
then the twin trained to the paper's criterion (mean of the last 100 training episodes > 1950)
through RLlib and, in the same run, by `twinbots train cartpole`.

    python benchmarks/rllib_speed.py [--sample-steps 8192] [--skip-training]

Needs `ray[rllib]` (scripts/test-python installs it into ~/.cache/twinbots/venv-rllib) and,
for the side-by-side, the `twinbots` binary (TWINBOTS_BIN, default target/release/twinbots)."""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import subprocess
import tempfile
import time
from pathlib import Path

import ray

from twinbots.rllib import ppo_config
from twinbots.rllib.train import RUNNER_ENV, TrainArgs, train


def sampling_rate(env_runners: int, steps: int) -> float:
    """Env steps/s of the remote env runners sampling `steps` each with the initial policy,
    all at once (the time of the slowest)."""
    algo = ppo_config("cartpole", env_runners=env_runners, envs_per_runner=8 // env_runners, seed=0).build_algo()
    group = algo.env_runner_group
    group.foreach_env_runner(lambda r: len(r.sample(num_timesteps=256)), local_env_runner=False)  # warm-up
    start = time.perf_counter()
    counts = group.foreach_env_runner(lambda r: sum(len(e) for e in r.sample(num_timesteps=steps)),
                                      local_env_runner=False)
    elapsed = time.perf_counter() - start
    algo.stop()
    return sum(counts) / elapsed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--sample-steps", type=int, default=8192)
    p.add_argument("--skip-training", action="store_true")
    a = p.parse_args()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR,
             runtime_env=RUNNER_ENV)
    for runners in (1, 2):
        rate = sampling_rate(runners, a.sample_steps // runners)
        print(f"sampling, {runners} env runner(s) × {8 // runners} arenas: {rate:.0f} env steps/s", flush=True)
    ray.shutdown()
    if a.skip_training:
        return

    with tempfile.TemporaryDirectory() as tmp:
        run = train(TrainArgs("cartpole", env_runners=2, envs_per_runner=4, timesteps=2_000_000, out=f"{tmp}/rllib"))
        s = json.loads((run / "rllib_summary.json").read_text())
        print(f"RLlib PPO (2 env runners × 4 arenas): {s['ended']} after {s['timesteps']} steps, "
              f"{s['wall_clock_s']:.1f} s", flush=True)

        binary = os.environ.get("TWINBOTS_BIN", str(Path(__file__).resolve().parents[2] / "target/release/twinbots"))
        start = time.perf_counter()
        out = subprocess.run([binary, "train", "cartpole", "--out", f"{tmp}/twinbots"],
                             capture_output=True, text=True, check=True)
        wall = time.perf_counter() - start
        solved = re.search(r"solved \(.*\) after (\d+) steps in ([\d.]+) s", out.stdout + out.stderr)
        steps = solved.group(1) if solved else "?"
        print(f"twinbots train cartpole (8 arenas): solved after {steps} steps, {wall:.1f} s wall clock", flush=True)


if __name__ == "__main__":
    main()
