"""Stable-Baselines3: the arenas as an SB3 `VecEnv` (SB3's own autoreset, SAME_STEP).

    from stable_baselines3 import PPO
    from twinbots.sb3 import make_vec_env
    model = PPO("MlpPolicy", make_vec_env("cartpole", n_envs=8, seed=0)).learn(100_000)
    # from pixels: PPO("CnnPolicy", make_vec_env("cartpole", n_envs=8, obs="pixels"))
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from ._arenas import open_arenas
from ._config import Config
from ._infos import episode_info
from ._spaces import ActionCheck, to_space
from ._thread import get_ident, on_owner_thread


class TwinbotsSB3VecEnv(VecEnv):
    """N arenas in SB3's `VecEnv` protocol. On the step an episode ends, that env's info holds
    `terminal_observation`, `TimeLimit.truncated` (truncated and not terminated), `episode`
    (`r`, `l`, `t`: what SB3's `Monitor` writes, so `ep_info_buffer` and the logger's
    `rollout/ep_rew_mean` work without a `VecMonitor`), `is_success` for tasks with a goal, and
    the task's figures (see `twinbots._infos.episode_info`)."""

    def __init__(self, robot: str, n_envs: int = 1, seed: int | None = None, task: str | None = None,
                 pattern: int = 1, config: Config = None, render_mode: str | None = None, calibration=None, log=None,
                 obs: str = "state", pixels: dict | None = None):
        self.arenas = open_arenas(robot, n_envs, seed, task, pattern, config, render_mode, count_name="n_envs",
                                  calibration=calibration, log=log, obs=obs, pixels=pixels)
        self._owner = get_ident()
        self.render_mode = render_mode  # read back by SB3's __init__ through get_attr
        super().__init__(int(n_envs), to_space(self.arenas.observation_space), to_space(self.arenas.action_space))
        self.render_mode = render_mode
        self._check = ActionCheck(self.action_space, self.num_envs)
        self._actions: np.ndarray | None = None
        self._start = time.time()
        if seed is not None:
            self.seed(seed)

    @on_owner_thread
    def reset(self):
        seed = self._seeds[0] if self._seeds and self._seeds[0] is not None else None
        obs = self.arenas.reset(seed)
        self._reset_seeds()
        self._reset_options()
        return obs

    @on_owner_thread
    def step_async(self, actions: np.ndarray) -> None:
        self._actions = self._check(actions)

    def step_wait(self):
        obs, rewards, terminated, truncated, ended = self.arenas.step(self._actions)
        dones = terminated | truncated
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i, final_obs, summary in ended:
            info = episode_info(summary)
            info["episode"]["t"] = round(time.time() - self._start, 6)
            info["terminal_observation"] = final_obs
            info["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            infos[i] = info
        return obs, rewards, dones, infos

    def close(self) -> None:
        if hasattr(self, "arenas") and get_ident() == self._owner:  # not when __init__ failed
            self.arenas.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        """Every env's frame, drawn in one frame by the renderer."""
        if self.render_mode != "rgb_array":
            raise RuntimeError("rendering is off: create the env with render_mode='rgb_array'")
        return list(self.arenas.render_all())

    # The arenas are one Rust app, not N Python envs: there are no per-env attributes or wrappers.
    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if attr_name == "render_mode":
            return [self.render_mode] * len(self._indices(indices))
        raise AttributeError(f"twinbots arenas have no attribute {attr_name!r}")

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError(f"cannot set {attr_name!r}: twinbots arenas have no per-env attributes")

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        raise AttributeError(f"twinbots arenas have no per-env method {method_name!r}")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices) -> list[int]:
        if indices is None:
            return list(range(self.arenas.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)


def make_vec_env(robot: str, n_envs: int = 1, *args, **kwargs) -> TwinbotsSB3VecEnv:
    """`n_envs` arenas of `robot` as an SB3 `VecEnv`: the arguments of `TwinbotsSB3VecEnv` (those
    of `twinbots.make_vec` but `autoreset_mode`)."""
    return TwinbotsSB3VecEnv(robot, n_envs, *args, **kwargs)
