"""The native arenas every env of the package steps, opened one way: the arguments checked,
the seed (fresh entropy when none is given, as Gymnasium does), the randomization settings,
and rendering when asked. The env that opens them keeps to their thread (`_thread`)."""

from __future__ import annotations

import os

import numpy as np

from . import _native
from ._config import Config, config_text, toml_keys


def initial_seed(seed: int | None) -> int:
    """The app's seed: `seed`, or fresh entropy when none is given (as Gymnasium does)."""
    if seed is None:
        return int(np.random.SeedSequence().entropy % (2**63))
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    return int(seed)


def pixels_text(obs: str, pixels: dict | None) -> str | None:
    """The `[pixels]` keys for the extension: None for `obs="state"`, the table (empty: the
    defaults) for `obs="pixels"`."""
    if obs not in ("state", "pixels"):
        raise ValueError(f"obs must be 'state' or 'pixels', got {obs!r}")
    if obs == "state":
        if pixels is not None:
            raise ValueError("pixels= sets up camera observations: pass obs='pixels' with it")
        return None
    if pixels is not None and not isinstance(pixels, dict):
        raise ValueError(f"pixels must be a dict of camera, width, height, frames; got {type(pixels).__name__}")
    return toml_keys(pixels or {})


def open_arenas(robot: str, count: int, seed: int | None, task: str | None, pattern: int, config: Config,
                render_mode: str | None, count_name: str = "num_envs", calibration=None, log=None,
                obs: str = "state", pixels: dict | None = None, **rendering) -> _native.Arenas:
    """`count` arenas of `robot`'s `task` under design pattern `pattern`, the twin calibrated by
    the file `calibration` if given, arena 0's episodes logged to the file `log` if given,
    observing camera images with `obs="pixels"` (`pixels`: the `[pixels]` keys, docs/pixels.md);
    `rendering` (width, height, camera) applies with `render_mode="rgb_array"`."""
    if not isinstance(count, (int, np.integer)) or count < 1:
        raise ValueError(f"{count_name} must be a positive integer, got {count!r}")
    if render_mode not in (None, "rgb_array"):
        raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
    calibration = None if calibration is None else os.fspath(calibration)
    log = None if log is None else os.fspath(log)
    pixel_keys = pixels_text(obs, pixels)
    arenas = _native.Arenas(robot, int(count), initial_seed(seed), task, pattern, config_text(config), calibration, log,
                            pixel_keys)
    if render_mode == "rgb_array":
        arenas.enable_rendering(**rendering)
    return arenas
