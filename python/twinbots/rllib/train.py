"""The RLlib training loop behind `python -m twinbots.rllib train`: one `algo.train()` per
iteration, a `progress.csv` row each (twinbots' columns), stop on the robot's solved criterion
or the budget, checkpoints, the learning curve, and the policy saved as a twinbots model."""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from .. import _native
from .config import ppo_config
from .handover import save_model

# RLlib's PPO checkpoint, beside twinbots' `model/` (which `twinbots eval` reads).
RLLIB_CHECKPOINT = "rllib_checkpoint"
SUMMARY = "rllib_summary.json"
# Ray's workers' environment: one core per env runner, so its arenas step on one thread
# (twinbots' pool, and torch's, would otherwise take every core of the node in every runner).
RUNNER_ENV = {"env_vars": {"RAYON_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}}


@dataclass
class TrainArgs:
    robot: str
    task: str | None = None
    env_runners: int = 2
    envs_per_runner: int | None = None
    address: str | None = None
    timesteps: int | None = None
    seed: int = 0
    out: str | None = None
    checkpoint_every: int = 10
    ray_logs: bool = False


class EpisodeWindow:
    """The last `size` finished episodes, from every runner: twinbots' figures (and solved
    criteria) are over the last 100 episodes, RLlib's `episode_return_mean` only over those
    that finished in the iteration."""

    def __init__(self, size: int = 100):
        self.returns: deque[float] = deque(maxlen=size)
        self.lengths: deque[float] = deque(maxlen=size)
        self.successes: deque[float] = deque(maxlen=size)
        self.count = 0

    def add(self, result: dict) -> None:
        custom = result.get("env_runners", {}).get("twinbots", {})

        def items(key: str) -> list[float]:
            # An item series of one item comes back as the item itself.
            value = custom.get(key, [])
            return list(value) if isinstance(value, (list, tuple)) else [value]

        returns = items("episode_returns")
        self.returns.extend(returns)
        self.lengths.extend(items("episode_lengths"))
        self.successes.extend(items("episode_successes"))
        self.count += len(returns)

    def figures(self) -> dict:
        out = {"episodes": self.count}
        if self.returns:
            out |= {
                "mean_reward": sum(self.returns) / len(self.returns),
                "min_reward": min(self.returns),
                "max_reward": max(self.returns),
                "mean_length": sum(self.lengths) / max(len(self.lengths), 1),
            }
        if self.successes:
            out["success_rate"] = sum(self.successes) / len(self.successes)
        return out

    def is_solved(self, solved: dict | None) -> bool:
        """The robot's criterion over the last `solved["window"]` episodes."""
        if solved is None:
            return False
        values = self.returns if solved["measure"] == "score" else self.successes
        recent = list(values)[-solved["window"]:]
        return len(recent) >= solved["window"] and sum(recent) / len(recent) > solved["threshold"]


def progress_row(result: dict, iteration: int, seconds: float, episodes: EpisodeWindow) -> dict:
    """One `progress.csv` row from an RLlib result and the episode window (missing figures are
    left out: NaN)."""
    runners = result.get("env_runners", {})
    learner = result.get("learners", {}).get("default_policy", {})
    row = {
        "update": iteration,
        "timesteps": result.get("num_env_steps_sampled_lifetime", runners.get("num_env_steps_sampled_lifetime", 0)),
        "policy_loss": learner.get("policy_loss"),
        "value_loss": learner.get("vf_loss"),
        "entropy": learner.get("entropy"),
        "learning_rate": learner.get("default_optimizer_learning_rate"),
        "steps_per_s": runners.get("num_env_steps_sampled", 0) / max(seconds, 1e-9),
    } | episodes.figures()
    return {k: float(v) for k, v in row.items() if v is not None and not (isinstance(v, float) and math.isnan(v))}


def runner_steps(result: dict) -> dict[int, int]:
    """Env steps sampled by each env runner in this iteration, by runner index."""
    custom = result.get("env_runners", {}).get("twinbots", {})
    return {int(k.split("_")[1]): int(v) for k, v in custom.items() if k.startswith("runner_") and k.endswith("_steps")}


def start_ray(address: str | None, env_runners: int, ray_logs: bool) -> bool:
    """Starts or joins Ray unless this process already runs it; True if it started it."""
    import ray

    if ray.is_initialized():
        return False
    quiet = {} if ray_logs else {"log_to_driver": False, "logging_level": logging.ERROR}
    if address is None:
        ray.init(num_cpus=max(os.cpu_count() or 1, env_runners), include_dashboard=False, runtime_env=RUNNER_ENV, **quiet)
    else:
        ray.init(address=address, runtime_env=RUNNER_ENV, **quiet)
    return True


def train(args: TrainArgs) -> Path:
    import ray

    defaults = _native.training_defaults(args.robot)
    timesteps = args.timesteps or defaults["timesteps"]
    run = Path(args.out or f"runs/rllib-{args.robot}-{int(time.time())}")
    config = ppo_config(args.robot, args.task, args.env_runners, args.envs_per_runner, args.seed, timesteps)
    solved = defaults["solved"] if args.task is None else None
    arenas = max(args.env_runners, 1) * config.num_envs_per_env_runner
    _native.create_run(os.fspath(run), args.robot, args.seed, arenas, timesteps)
    owns_ray = start_ray(args.address, args.env_runners, args.ray_logs)
    try:
        try:
            algo = config.build_algo()
        except Exception as e:
            hint = "" if args.ray_logs else " (run again with --ray-logs to see the env runners' errors)"
            raise RuntimeError(f"RLlib could not build PPO for {args.robot}: {type(e).__name__}: {e}{hint}") from e
        started = time.time()
        iteration, row, ended, per_runner, saved = 0, {}, "budget spent", {}, None
        episodes = EpisodeWindow(solved["window"] if solved else 100)
        while row.get("timesteps", 0) < timesteps:
            t = time.time()
            result = algo.train()
            iteration += 1
            episodes.add(result)
            row = progress_row(result, iteration, time.time() - t, episodes)
            for k, v in runner_steps(result).items():
                per_runner[k] = per_runner.get(k, 0) + v
            _native.append_progress(os.fspath(run), row)
            print(
                f"iteration {iteration}: {int(row.get('timesteps', 0))} steps, {row.get('steps_per_s', 0):.0f} steps/s, "
                f"mean reward {row.get('mean_reward', math.nan):.1f}"
                + (f", success {row['success_rate']:.2f}" if "success_rate" in row else ""),
                flush=True,
            )
            if iteration % max(args.checkpoint_every, 1) == 0:
                checkpoint(algo, run, args, row)
                saved = iteration
            if episodes.is_solved(solved):
                ended = "solved"
                break
        wall = time.time() - started
        if saved != iteration:
            checkpoint(algo, run, args, row)
        title = f"{args.robot} (RLlib PPO, {args.env_runners} env runners × {config.num_envs_per_env_runner} arenas)"
        _native.draw_curve(os.fspath(run), args.robot, title)
        summary = {
            "robot": args.robot,
            "task": args.task,
            "ended": ended,
            "timesteps": int(row.get("timesteps", 0)),
            "iterations": iteration,
            "wall_clock_s": round(wall, 2),
            "env_runners": args.env_runners,
            "envs_per_runner": config.num_envs_per_env_runner,
            "steps_per_runner": {str(k): v for k, v in sorted(per_runner.items())},
            "mean_reward": row.get("mean_reward"),
        }
        (run / SUMMARY).write_text(json.dumps(summary, indent=2) + "\n")
        print(f"{ended} after {summary['timesteps']} steps in {wall:.1f} s; run directory: {run}")
        algo.stop()
    finally:
        if owns_ray:
            ray.shutdown()
    return run


def checkpoint(algo, run: Path, args: TrainArgs, row: dict) -> None:
    """RLlib's own checkpoint (to resume in RLlib) and the policy as twinbots' `model/`."""
    algo.save_to_path(os.fspath((run / RLLIB_CHECKPOINT).resolve()))
    save_model(algo, run, args.robot, args.task, args.seed, int(row.get("timesteps", 0)), int(row.get("episodes", 0)))
