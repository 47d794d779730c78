"""Gymnasium spaces from the task's own declaration, and the checks an action passes before the
simulation sees it."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces


def to_space(d: dict) -> spaces.Space:
    """A Gymnasium space from the extension's description (the Rust `Space`)."""
    kind = d["kind"]
    if kind == "box":
        return spaces.Box(
            low=np.asarray(d["low"], dtype=np.float32),
            high=np.asarray(d["high"], dtype=np.float32),
            dtype=np.float32,
        )
    if kind == "discrete":
        return spaces.Discrete(d["n"])
    if kind == "image":
        # What SB3's CnnPolicy recognises as an image (uint8, bounds 0 and 255, channels last).
        return spaces.Box(low=0, high=255, shape=tuple(d["shape"]), dtype=np.uint8)
    if kind == "multi_discrete":
        return spaces.MultiDiscrete(np.asarray(d["nvec"], dtype=np.int64))
    if kind == "image_and_state":
        # A camera image and the robot's own state (`pixels.state`): SB3's MultiInputPolicy.
        return spaces.Dict({
            "image": to_space({"kind": "image", "shape": d["shape"]}),
            "state": to_space({"kind": "box", "low": d["low"], "high": d["high"]}),
        })
    raise ValueError(f"unknown space kind {kind!r}")


def obs_row(obs, i: int):
    """Env `i`'s observation in a batch: its row, or each key's row of a Dict observation."""
    return {k: v[i] for k, v in obs.items()} if isinstance(obs, dict) else obs[i]


def set_obs_row(obs, i: int, value) -> None:
    """Puts `value` as env `i`'s observation in a batch (each key's row of a Dict observation)."""
    if isinstance(obs, dict):
        for k, v in obs.items():
            v[i] = value[k]
    else:
        obs[i] = value


# Action dtypes the extension reads as they are (`actions::action_values`); others are cast here.
_AS_IS = frozenset(np.dtype(t) for t in (np.float32, np.float64, np.int64, np.int32))


class ActionCheck:
    """Turns the actions of `num_envs` envs into an array the extension takes (float32, float64,
    int64 or int32, as they are when they come so; anything else cast to flat float32), or
    raises `ValueError` for a wrong shape or dtype. The values themselves (NaN, infinity, a
    choice out of range or fractional) are checked by the extension before any arena sees
    them, where it costs nanoseconds; boxes are clipped to their bounds there."""

    def __init__(self, space: spaces.Space, num_envs: int):
        self.space = space
        self.num_envs = num_envs
        self.discrete = isinstance(space, spaces.Discrete)
        if isinstance(space, spaces.Box):
            self.shape = (num_envs, *space.shape)
        elif self.discrete:
            self.shape = (num_envs,)
        else:
            self.shape = (num_envs, len(space.nvec))

    def __call__(self, actions) -> np.ndarray:
        if type(actions) is np.ndarray and actions.shape == self.shape and actions.dtype in _AS_IS:
            return actions  # the extension reads these as they are: no copy, no numpy calls
        a = np.asarray(actions)
        if a.shape != self.shape:
            if self.discrete and a.shape == (self.num_envs, 1):
                a = a[:, 0]  # SB3 and some policies keep a trailing axis of 1
            else:
                raise ValueError(f"actions have shape {a.shape}, expected {self.shape} for {self.space}")
        if a.dtype.kind not in "fiu":
            raise ValueError(f"actions must be real numbers, got dtype {a.dtype}")
        return a.astype(np.float32, copy=False).reshape(-1)
