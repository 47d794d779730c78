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
    if kind == "multi_discrete":
        return spaces.MultiDiscrete(np.asarray(d["nvec"], dtype=np.int64))
    raise ValueError(f"unknown space kind {kind!r}")


class ActionCheck:
    """Turns the actions of `num_envs` envs into the flat float32 vector the extension takes,
    or raises `ValueError` saying what is wrong: shape, dtype, NaN or infinity, a choice out of
    range. Boxes are clipped to their bounds (as Stable-Baselines3 does before stepping)."""

    def __init__(self, space: spaces.Space, num_envs: int):
        self.space = space
        self.num_envs = num_envs
        if isinstance(space, spaces.Box):
            self.shape = (num_envs, *space.shape)
            self.low, self.high = space.low, space.high
            self.choices = None
        elif isinstance(space, spaces.Discrete):
            self.shape = (num_envs,)
            self.choices = np.int64(space.n)
        else:
            self.shape = (num_envs, len(space.nvec))
            self.choices = space.nvec

    def __call__(self, actions) -> np.ndarray:
        a = np.asarray(actions)
        if a.shape != self.shape:
            if isinstance(self.space, spaces.Discrete) and a.shape == (self.num_envs, 1):
                a = a[:, 0]  # SB3 and some policies keep a trailing axis of 1
            else:
                raise ValueError(f"actions have shape {a.shape}, expected {self.shape} for {self.space}")
        kind = a.dtype.kind
        if kind not in "fiu":
            raise ValueError(f"actions must be real numbers, got dtype {a.dtype}")
        if kind == "f" and not np.isfinite(a).all():
            bad = np.argwhere(~np.isfinite(a))[0]
            raise ValueError(f"action of env {bad[0]} is {a[tuple(bad)]} (NaN or infinite)")
        if self.choices is None:
            return np.clip(a, self.low, self.high, dtype=np.float32).reshape(-1)
        if kind == "f" and not (a == np.round(a)).all():
            raise ValueError(f"actions of {self.space} must be whole numbers, got {a}")
        if (a < 0).any() or (a >= self.choices).any():
            raise ValueError(f"actions {a} are out of {self.space}")
        return np.ascontiguousarray(a, dtype=np.float32).reshape(-1)
