"""Ray RLlib on the twins: each env runner steps a `twinbots.make_vec` of N arenas in Rust.

    import ray
    from twinbots.rllib import ppo_config
    ray.init()
    algo = ppo_config("cartpole", env_runners=2, envs_per_runner=4).build_algo()
    result = algo.train()

`python -m twinbots.rllib train cartpole` does this with a run directory like `twinbots
train`'s (see docs/rllib.md). Needs `ray[rllib]` (not a dependency of twinbots)."""

from .config import ppo_config
from .env import env_name, register_env
from .handover import save_model

__all__ = ["ppo_config", "register_env", "env_name", "save_model"]
