"""twinbots: robot digital twins as Gymnasium environments, simulated in Rust.

    import twinbots
    envs = twinbots.make_vec("cartpole", num_envs=8, seed=0)   # a gymnasium.vector.VectorEnv
    env = gymnasium.make("twinbots/cartpole-v0")                 # a single env
    policy = twinbots.load_policy("runs/cartpole")               # a model `twinbots train` wrote
"""

from __future__ import annotations

from . import _native
from ._config import Config  # noqa: F401 (re-exported: twinbots.Config, the type of every config=)
from .env import TwinbotsEnv
from .policy import Policy, load_policy
from .registration import env_ids, register_all
from .vector import TwinbotsVectorEnv

__all__ = ["make_vec", "make", "robots", "env_ids", "load_policy", "Policy", "TwinbotsEnv", "TwinbotsVectorEnv"]


def robots() -> list[dict]:
    """The built-in robots: name, description, tasks `(name, description)`, patterns."""
    return _native.robots()


def make_vec(robot: str, num_envs: int = 1, *args, **kwargs) -> TwinbotsVectorEnv:
    """`num_envs` arenas of `robot` as a `gymnasium.vector.VectorEnv` stepped in Rust: the
    arguments of `TwinbotsVectorEnv` (seed, task, pattern, config, render_mode, autoreset_mode,
    calibration, log), where they are described."""
    return TwinbotsVectorEnv(robot, num_envs, *args, **kwargs)


def make(robot: str, *args, **kwargs) -> TwinbotsEnv:
    """One arena of `robot` as a `gymnasium.Env` (without Gymnasium's wrappers): the arguments
    of `TwinbotsEnv`."""
    return TwinbotsEnv(robot, *args, **kwargs)


register_all()
