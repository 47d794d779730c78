"""The twins as RLlib environments: one `TwinbotsVectorEnv` per env runner (its arenas are the
runner's `num_envs_per_env_runner`), in the NEXT_STEP autoreset mode RLlib's env runners
expect (the step after an episode's end returns the next episode's first observation)."""

from __future__ import annotations

from .. import make_vec


def env_name(robot: str, task: str | None = None) -> str:
    """The name `register_env` registers `robot`'s `task` under."""
    return f"twinbots-{robot}" + (f"-{task}" if task else "")


def register_env(robot: str, task: str | None = None) -> str:
    """Registers `robot`'s `task` with Ray Tune (on this process; RLlib registers it again on
    every worker) and returns the name to pass to `config.environment(...)`. Use it with
    `gym_env_vectorize_mode=gymnasium.VectorizeMode.VECTOR_ENTRY_POINT` (as `ppo_config` does):
    RLlib then asks for `num_envs` arenas at once instead of wrapping single envs."""
    from ray import tune

    name = env_name(robot, task)

    def create(env_config):
        num_envs = int(env_config.get("num_envs", 1))
        # `env_config={"obs": "pixels", "pixels": {...}}`: camera images (docs/pixels.md).
        return make_vec(robot, num_envs=num_envs, task=task, autoreset_mode="NEXT_STEP",
                        obs=env_config.get("obs", "state"), pixels=env_config.get("pixels"))

    tune.register_env(name, create)
    return name
