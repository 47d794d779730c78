"""twinbots: robot digital twins as Gymnasium environments, simulated in Rust.

    import twinbots
    envs = twinbots.make_vec("cartpole", num_envs=8, seed=0)   # a gymnasium.vector.VectorEnv
    env = gymnasium.make("twinbots/cartpole-v0")                 # a single env
    policy = twinbots.load_policy("runs/cartpole")               # a model `twinbots train` wrote
"""

from __future__ import annotations

from . import _native
from ._config import Config
from .env import TwinbotsEnv
from .policy import Policy, load_policy
from .registration import env_ids, register_all
from .vector import TwinbotsVectorEnv

__all__ = ["make_vec", "make", "robots", "env_ids", "load_policy", "Policy", "TwinbotsEnv", "TwinbotsVectorEnv"]


def robots() -> list[dict]:
    """The built-in robots: name, description, tasks `(name, description)`, patterns."""
    return _native.robots()


def make_vec(
    robot: str,
    num_envs: int = 1,
    seed: int | None = None,
    task: str | None = None,
    pattern: int = 1,
    config: Config = None,
    render_mode: str | None = None,
    autoreset_mode="SAME_STEP",
    calibration=None,
    log=None,
) -> TwinbotsVectorEnv:
    """`num_envs` arenas of `robot` as a `gymnasium.vector.VectorEnv` stepped in Rust.

    `task`: None for the robot's main task; `pattern`: the paper's design pattern 1
    (Supervisor) or 2 (radio); `config`: domain randomization (a TOML file or text with a
    `[randomization]` table, or a dict of it); `autoreset_mode`: "SAME_STEP" or "NEXT_STEP";
    `calibration`: a calibration file (`twinbots identify`'s calibration.toml) the twin runs
    with; `log`: a robot log file (`.mcap` or `.csv`, docs/logs.md) that holds arena 0's latest
    episode, rewritten as each ends (`close()` adds the running one)."""
    return TwinbotsVectorEnv(robot, num_envs, seed, task, pattern, config, render_mode, autoreset_mode, calibration, log)


def make(robot: str, task: str | None = None, **kwargs) -> TwinbotsEnv:
    """One arena of `robot` as a `gymnasium.Env` (without Gymnasium's wrappers)."""
    return TwinbotsEnv(robot, task, **kwargs)


register_all()
