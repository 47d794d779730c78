"""`TwinbotsEnv`: one arena of a twin as a `gymnasium.Env` (what `gymnasium.make` returns)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from ._arenas import open_arenas
from ._config import Config
from ._infos import episode_info
from ._spaces import ActionCheck, obs_row, to_space
from ._thread import get_ident, on_owner_thread


class TwinbotsEnv(gym.Env):
    """A single arena. The episode's end is the task's own: its termination terms and time
    limit (truncation). After an episode ended, call `reset()`; the arena has already drawn
    its next start, which `reset()` returns (with `seed=`, it re-seeds and draws again)."""

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(
        self,
        robot: str,
        task: str | None = None,
        pattern: int = 1,
        config: Config = None,
        seed: int | None = None,
        render_mode: str | None = None,
        camera: str = "iso",
        width: int = 640,
        height: int = 480,
        calibration=None,
        log=None,
        obs: str = "state",
        pixels: dict | None = None,
    ):
        self.arenas = open_arenas(
            robot, 1, seed, task, pattern, config, render_mode, calibration=calibration, log=log, obs=obs,
            pixels=pixels, width=width, height=height, camera=camera,
        )
        self._owner = get_ident()
        self.task = self.arenas.task
        self.observation_space = to_space(self.arenas.observation_space)
        self.action_space = to_space(self.arenas.action_space)
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": round(1.0 / self.arenas.control_dt)}
        self.render_mode = render_mode
        self._check = ActionCheck(self.action_space, 1)
        self._next_start: np.ndarray | None = None  # the arena's fresh start after an episode ended
        self._ended = False
        self._reset_once = False

    @on_owner_thread
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if seed is not None and (not isinstance(seed, (int, np.integer)) or seed < 0):
            raise ValueError(f"seed must be a non-negative int, got {seed!r}")
        if options:
            raise ValueError(f"reset options are not supported, got {options!r}")
        if seed is None and self._next_start is not None:
            obs = self._next_start  # drawn when the last episode ended, never stepped
        else:
            obs = obs_row(self.arenas.reset(None if seed is None else int(seed)), 0)
        self._next_start, self._ended, self._reset_once = None, False, True
        return obs, {}

    @on_owner_thread
    def step(self, action):
        if not self._reset_once:
            raise RuntimeError("call reset() before step()")
        if self._ended:
            raise RuntimeError("the episode has ended (terminated or truncated): call reset() before stepping again")
        flat = self._check(np.asarray(action)[None])
        obs, rewards, terminated, truncated, ended = self.arenas.step(flat)
        info: dict[str, Any] = {}
        if ended:
            _, final_obs, summary = ended[0]
            self._next_start, self._ended = obs_row(obs, 0), True
            info = episode_info(summary)
            return final_obs, float(rewards[0]), bool(terminated[0]), bool(truncated[0]), info
        self._next_start = None
        return obs_row(obs, 0), float(rewards[0]), bool(terminated[0]), bool(truncated[0]), info

    @on_owner_thread
    def render(self):
        """Arena 0 as an RGB image `(height, width, 3)`, with `render_mode="rgb_array"`."""
        if self.render_mode is None:
            gym.logger.warn("render() without a render_mode: create the env with render_mode='rgb_array'")
            return None
        return self.arenas.render()

    def close(self):
        if hasattr(self, "arenas") and get_ident() == self._owner:  # not when __init__ failed
            self.arenas.close()
