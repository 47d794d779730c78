"""The RLlib training loop behind `python -m twinbots.rllib train`: one `algo.train()` per
iteration, a `progress.csv` row each (twinbots' columns), stop on the robot's solved criterion
or the budget, checkpoints, the learning curve, and the policy saved as a twinbots model.
`resume` continues a run from its checkpoint (RLlib's state plus twinbots' counters and
episode window), with `progress.csv` cut back to it."""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
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
# The command's arguments (budget resolved), for `--resume`.
ARGS = "rllib_args.json"
# Inside a checkpoint: twinbots' counters and episode window at that point.
STATE = "twinbots_state.json"
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

    def state(self) -> dict:
        return {"returns": list(self.returns), "lengths": list(self.lengths), "successes": list(self.successes),
                "count": self.count}

    def restore(self, state: dict) -> None:
        self.returns.extend(state["returns"])
        self.lengths.extend(state["lengths"])
        self.successes.extend(state["successes"])
        self.count = state["count"]

    def is_solved(self, solved: dict | None) -> bool:
        """The robot's criterion over the last `solved["window"]` episodes."""
        if solved is None:
            return False
        values = self.returns if solved["measure"] == "score" else self.successes
        recent = list(values)[-solved["window"]:]
        return len(recent) >= solved["window"] and sum(recent) / len(recent) > solved["threshold"]


def progress_row(result: dict, iteration: int, seconds: float, episodes: EpisodeWindow,
                 timesteps: int | None = None) -> dict:
    """One `progress.csv` row from an RLlib result and the episode window (missing figures are
    left out: NaN). `timesteps`: the run's count (default: RLlib's lifetime count)."""
    runners = result.get("env_runners", {})
    learner = result.get("learners", {}).get("default_policy", {})
    if timesteps is None:
        timesteps = result.get("num_env_steps_sampled_lifetime", runners.get("num_env_steps_sampled_lifetime", 0))
    row = {
        "update": iteration,
        "timesteps": timesteps,
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
    # A runner that sampled nothing this iteration (lost with its node, restarting) reports NaN.
    return {int(k.split("_")[1]): int(v) for k, v in custom.items()
            if k.startswith("runner_") and k.endswith("_steps") and math.isfinite(v)}


def start_ray(address: str | None, env_runners: int, ray_logs: bool) -> bool:
    """Starts or joins Ray unless this process already runs it; True if it started it."""
    import ray

    if ray.is_initialized():
        return False
    quiet = {} if ray_logs else {"log_to_driver": False, "logging_level": logging.ERROR}
    if address is None:
        ray.init(num_cpus=max(os.cpu_count() or 1, env_runners), include_dashboard=False, runtime_env=RUNNER_ENV,
                 **quiet)
    else:
        ray.init(address=address, runtime_env=RUNNER_ENV, **quiet)
    return True


@dataclass
class Progress:
    """Where a run stands: what a checkpoint keeps besides RLlib's own state."""

    iteration: int = 0
    timesteps: int = 0
    wall_s: float = 0.0
    per_runner: dict | None = None
    episodes: dict | None = None

    @staticmethod
    def read(checkpoint: Path) -> Progress:
        return Progress(**json.loads((checkpoint / STATE).read_text()))


def train(args: TrainArgs) -> Path:
    """A new run into `args.out`."""
    defaults = _native.training_defaults(args.robot)
    args.timesteps = args.timesteps or defaults["timesteps"]
    run = Path(args.out or f"runs/rllib-{args.robot}-{int(time.time())}")
    config = ppo_config(args.robot, args.task, args.env_runners, args.envs_per_runner, args.seed, args.timesteps)
    arenas = max(args.env_runners, 1) * config.num_envs_per_env_runner
    _native.create_run(os.fspath(run), args.robot, args.seed, arenas, args.timesteps)
    (run / ARGS).write_text(json.dumps(vars(args) | {"out": os.fspath(run)}, indent=2) + "\n")
    return _run(args, run, config, None)


def resume(run: str | Path, address: str | None = None) -> Path:
    """Continues the run in `run` from its checkpoint, to the run's own budget."""
    run = Path(run)
    if not (run / ARGS).is_file():
        raise ValueError(f"{run}: not a run of `python -m twinbots.rllib train` (no {ARGS})")
    args = TrainArgs(**json.loads((run / ARGS).read_text()))
    args.address = address or args.address
    checkpoint = latest_checkpoint(run)
    config = ppo_config(args.robot, args.task, args.env_runners, args.envs_per_runner, args.seed, args.timesteps)
    return _run(args, run, config, checkpoint)


def latest_checkpoint(run: Path) -> Path:
    """The run's complete checkpoint: the current one, else the one a kill mid-save left."""
    for name in (RLLIB_CHECKPOINT, RLLIB_CHECKPOINT + ".old"):
        if (run / name / STATE).is_file():
            return run / name
    raise ValueError(f"{run}: no complete checkpoint to resume from")


def _run(args: TrainArgs, run: Path, config, checkpoint: Path | None) -> Path:
    import ray

    defaults = _native.training_defaults(args.robot)
    solved = defaults["solved"] if args.task is None else None
    owns_ray = start_ray(args.address, args.env_runners, args.ray_logs)
    try:
        try:
            algo = config.build_algo()
        except Exception as e:
            hint = "" if args.ray_logs else " (run again with --ray-logs to see the env runners' errors)"
            raise RuntimeError(f"RLlib could not build PPO for {args.robot}: {type(e).__name__}: {e}{hint}") from e
        episodes = EpisodeWindow(solved["window"] if solved else 100)
        progress = Progress(per_runner={})
        if checkpoint is not None:
            algo.restore_from_path(os.fspath(checkpoint.resolve()))
            progress = Progress.read(checkpoint)
            episodes.restore(progress.episodes)
            progress.per_runner = {int(k): v for k, v in progress.per_runner.items()}
            # The rows logged after the checkpoint are redone.
            _native.truncate_progress(os.fspath(run), progress.timesteps)
            print(f"resuming {run} from {checkpoint} ({progress.timesteps} steps, iteration {progress.iteration})",
                  flush=True)
        started = time.time() - progress.wall_s
        row, ended, saved = {}, "budget spent", progress.iteration
        while progress.timesteps < args.timesteps:
            t = time.time()
            result = algo.train()
            progress.iteration += 1
            progress.timesteps += int(result.get("env_runners", {}).get("num_env_steps_sampled", 0))
            episodes.add(result)
            row = progress_row(result, progress.iteration, time.time() - t, episodes, progress.timesteps)
            for k, v in runner_steps(result).items():
                progress.per_runner[k] = progress.per_runner.get(k, 0) + v
            _native.append_progress(os.fspath(run), row)
            print(
                f"iteration {progress.iteration}: {progress.timesteps} steps, {row.get('steps_per_s', 0):.0f} steps/s, "
                f"mean reward {row.get('mean_reward', math.nan):.1f}"
                + (f", success {row['success_rate']:.2f}" if "success_rate" in row else ""),
                flush=True,
            )
            progress.wall_s = time.time() - started
            if progress.iteration % max(args.checkpoint_every, 1) == 0:
                save_checkpoint(algo, run, args, progress, episodes)
                saved = progress.iteration
            if episodes.is_solved(solved):
                ended = "solved"
                break
        wall = time.time() - started
        if saved != progress.iteration:
            save_checkpoint(algo, run, args, progress, episodes)
        title = f"{args.robot} (RLlib PPO, {args.env_runners} env runners × {config.num_envs_per_env_runner} arenas)"
        _native.draw_curve(os.fspath(run), args.robot, title)
        summary = {
            "robot": args.robot,
            "task": args.task,
            "ended": ended,
            "timesteps": progress.timesteps,
            "iterations": progress.iteration,
            "wall_clock_s": round(wall, 2),
            "env_runners": args.env_runners,
            "envs_per_runner": config.num_envs_per_env_runner,
            "steps_per_runner": {str(k): v for k, v in sorted(progress.per_runner.items())},
            "mean_reward": row.get("mean_reward"),
        }
        (run / SUMMARY).write_text(json.dumps(summary, indent=2) + "\n")
        # As every twinbots run ends: the model evaluated into eval.json, and summary.json.
        evaluation = _native.finish_run(os.fspath(run), ended == "solved", wall)
        print(f"{ended} after {summary['timesteps']} steps in {wall:.1f} s; run directory: {run}")
        print(f"evaluation of the final model, {evaluation}")
        algo.stop()
    finally:
        if owns_ray:
            ray.shutdown()
    return run


def save_checkpoint(algo, run: Path, args: TrainArgs, progress: Progress, episodes: EpisodeWindow) -> None:
    """RLlib's own state with twinbots' counters (to resume), and the policy as twinbots'
    `model/`. Written beside the old checkpoint and swapped in by renames, so a kill at any
    moment leaves a complete one (`latest_checkpoint`)."""
    final, new, old = (run / (RLLIB_CHECKPOINT + suffix) for suffix in ("", ".new", ".old"))
    shutil.rmtree(new, ignore_errors=True)
    algo.save_to_path(os.fspath(new.resolve()))
    state = vars(progress) | {"per_runner": {str(k): v for k, v in progress.per_runner.items()},
                              "episodes": episodes.state()}
    (new / STATE).write_text(json.dumps(state))
    if final.exists():
        shutil.rmtree(old, ignore_errors=True)
        final.rename(old)
    new.rename(final)
    shutil.rmtree(old, ignore_errors=True)
    save_model(algo, run, args.robot, args.task, args.seed, progress.timesteps, episodes.count)
