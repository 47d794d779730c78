"""`python -m twinbots.rllib train <robot>`: trains a twin with RLlib's PPO on a local Ray or a
cluster, into a run directory like `twinbots train` writes (see docs/rllib.md)."""

from __future__ import annotations

import argparse
import sys

from .train import TrainArgs, resume, train


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m twinbots.rllib", description=__doc__)
    commands = parser.add_subparsers(dest="command", required=True)
    t = commands.add_parser("train", help="train a robot's task with RLlib's PPO")
    t.add_argument("robot", nargs="?", help="the robot to train (not with --resume)")
    t.add_argument("--resume", default=None, metavar="RUN",
                   help="continue this run from its checkpoint (its own settings)")
    t.add_argument("--task", default=None, help="one of the robot's tasks (default: its main task)")
    t.add_argument("--env-runners", type=int, default=2, help="env runner processes (default 2)")
    t.add_argument("--envs-per-runner", type=int, default=None,
                   help="arenas per runner (default: the robot's arenas / runners)")
    t.add_argument("--address", default=None,
                   help="a Ray cluster to join: 'auto' or ray://host:port (default: start a local Ray)")
    t.add_argument("--timesteps", type=int, default=None, help="env steps budget (default: the robot's)")
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--out", default=None, help="run directory (default runs/rllib-<robot>-<time>)")
    t.add_argument("--checkpoint-every", type=int, default=10, help="iterations between checkpoints (default 10)")
    t.add_argument("--ray-logs", action="store_true", help="show Ray's own logs (hidden by default)")
    a = parser.parse_args(argv)
    try:
        if a.resume is not None:
            if a.robot is not None:
                raise ValueError("--resume continues a run with its own settings: give no robot")
            resume(a.resume, a.address)
            return 0
        if a.robot is None:
            raise ValueError("give a robot to train, or --resume RUN")
        train(TrainArgs(a.robot, a.task, a.env_runners, a.envs_per_runner, a.address, a.timesteps, a.seed, a.out,
                        a.checkpoint_every, a.ray_logs))
    except (ValueError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
