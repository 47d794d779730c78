"""`TwinbotsVectorEnv`: N arenas of a twin as a `gymnasium.vector.VectorEnv`, stepped in Rust."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from ._arenas import open_arenas
from ._config import Config
from ._infos import vector_infos
from ._spaces import ActionCheck, set_obs_row, to_space
from ._thread import get_ident, on_owner_thread


def _autoreset_mode(mode) -> AutoresetMode:
    if isinstance(mode, AutoresetMode):
        return mode
    try:
        return AutoresetMode(mode) if mode in ("SameStep", "NextStep") else AutoresetMode[str(mode).upper()]
    except (KeyError, ValueError):
        raise ValueError(f"autoreset_mode must be SAME_STEP or NEXT_STEP, got {mode!r}") from None


class TwinbotsVectorEnv(gym.vector.VectorEnv):
    """`num_envs` arenas of `robot`'s `task`, simulated together in one Rust app.

    Autoreset is SAME_STEP by default (the simulation's own): an env whose episode ended
    returns the first observation of its next episode, with the last one in
    `info["final_obs"]` and the episode's figures in `info["final_info"]` (and `episode`,
    `is_success`, ... at the top level, masked by `_episode`, ...). NEXT_STEP returns the last
    observation and begins the next episode on the following step, whose action that env
    ignores.

    `task`: None for the robot's main task; `pattern`: the paper's design pattern 1
    (Supervisor) or 2 (radio); `config`: domain randomization (a TOML file or text with a
    `[randomization]` table, or a dict of it); `calibration`: a calibration file (`twinbots
    identify`'s calibration.toml) the twin runs with; `log`: a robot log file (`.mcap` or
    `.csv`, docs/logs.md) that holds arena 0's latest episode, rewritten as each ends
    (`close()` adds the running one); `obs="pixels"`: the envs observe a camera image
    (`uint8`, `(height, width, 3·frames)`) instead of the task's state, `pixels` its settings
    (`{"camera": "front", "width": 64, "height": 64, "frames": 1}`, docs/pixels.md).
    `TwinbotsEnv` and the SB3 `VecEnv` take the same."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"]}

    def __init__(
        self,
        robot: str,
        num_envs: int = 1,
        seed: int | None = None,
        task: str | None = None,
        pattern: int = 1,
        config: Config = None,
        render_mode: str | None = None,
        autoreset_mode: str | AutoresetMode = AutoresetMode.SAME_STEP,
        calibration=None,
        log=None,
        obs: str = "state",
        pixels: dict | None = None,
    ):
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        if self.autoreset_mode == AutoresetMode.DISABLED:
            raise ValueError("autoreset_mode DISABLED is not supported: "
                             "the arenas reset themselves (SAME_STEP or NEXT_STEP)")
        self.arenas = open_arenas(robot, num_envs, seed, task, pattern, config, render_mode, calibration=calibration,
                                  log=log, obs=obs, pixels=pixels)
        self._owner = get_ident()
        self.num_envs = int(num_envs)
        self.task = self.arenas.task
        self.single_observation_space = to_space(self.arenas.observation_space)
        self.single_action_space = to_space(self.arenas.action_space)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.metadata = {
            "autoreset_mode": self.autoreset_mode,
            "render_modes": ["rgb_array"],
            "render_fps": round(1.0 / self.arenas.control_dt),
        }
        self.render_mode = render_mode
        self._check = ActionCheck(self.single_action_space, self.num_envs)
        self._restart: list[int] = []  # NEXT_STEP: envs whose next step begins a new episode
        self._reset_once = False

    @on_owner_thread
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Resets every env. `seed` (an int) seeds them all: env i draws from stream i of it."""
        if seed is not None:
            if not isinstance(seed, (int, np.integer)) or seed < 0:
                raise ValueError(f"seed must be a non-negative int (env i gets stream i of it), got {seed!r}")
            self._np_random, self._np_random_seed = seeding.np_random(int(seed))
        if options:
            raise ValueError(f"reset options are not supported, got {options!r}")
        self._restart = []
        self._reset_once = True
        return self.arenas.reset(None if seed is None else int(seed)), {}

    @on_owner_thread
    def step(self, actions):
        if not self._reset_once:
            raise RuntimeError("call reset() before step()")
        flat = self._check(actions)
        if self.autoreset_mode == AutoresetMode.SAME_STEP:
            # The extension builds the infos itself (`vector_infos`'s layout), none when no episode ended.
            obs, rewards, terminated, truncated, infos = self.arenas.step(flat, None, True)
            return obs, rewards, terminated, truncated, infos or {}
        obs, rewards, terminated, truncated, ended = self.arenas.step(flat, self._restart or None)
        self._restart = [i for i, _, _ in ended]
        if not ended:
            return obs, rewards, terminated, truncated, {}
        for i, final_obs, _ in ended:
            set_obs_row(obs, i, final_obs)  # the next step begins env i's next episode
        return obs, rewards, terminated, truncated, vector_infos(self.num_envs, ended, final_obs=False)

    @on_owner_thread
    def render(self):
        """Every env's frame (`render_mode="rgb_array"`), as Gymnasium's vector envs return
        them: a tuple of `(height, width, 3)` uint8 images, views of one `(num_envs, height,
        width, 3)` array that the renderer draws in one frame (`render_all()` returns it)."""
        if self.render_mode is None:
            return None
        return tuple(self.arenas.render_all())

    @on_owner_thread
    def render_all(self):
        """Every env's frame as one `(num_envs, height, width, 3)` uint8 array."""
        if self.render_mode is None:
            raise RuntimeError("rendering is off: create the env with render_mode='rgb_array'")
        return self.arenas.render_all()

    def close_extras(self, **kwargs):
        # Not when __init__ failed (close() runs from __del__).
        if hasattr(self, "arenas") and get_ident() == self._owner:
            self.arenas.close()
