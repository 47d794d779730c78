"""`load_policy`: the model `twinbots train` wrote, acting in Python exactly as in Rust."""

from __future__ import annotations

import os

import numpy as np

from . import _native
from ._spaces import to_space


class Policy:
    """A trained policy of any algorithm (`twinbots algos`; its observation normaliser
    included); `algorithm` says which trained it. `predict` follows
    Stable-Baselines3: `action, state = policy.predict(obs, deterministic=True)`, `state` always
    None; `obs` is one observation or a batch."""

    def __init__(self, path: str | os.PathLike):
        self._model = _native.Policy(os.fspath(path))
        self.path = self._model.path
        self.algorithm = self._model.algorithm
        self.observation_space = to_space(self._model.observation_space)
        self.action_space = to_space(self._model.action_space)

    def predict(self, obs, state=None, episode_start=None, deterministic: bool = True):
        if isinstance(obs, dict):  # an image and state: rows of the image's values, then the state's
            image, values = (np.asarray(obs[k], dtype=np.float32) for k in ("image", "state"))
            single = image.ndim == 3
            rows = 1 if single else image.shape[0]
            batch = np.concatenate([image.reshape(rows, -1), values.reshape(rows, -1)], axis=1)
        else:
            x = np.asarray(obs, dtype=np.float32)
            k = len(self.observation_space.shape)
            if x.ndim not in (k, k + 1) or x.shape[x.ndim - k:] != self.observation_space.shape:
                raise ValueError(f"observations have shape {x.shape}, "
                                 f"expected {self.observation_space.shape} or (batch, *that)")
            single = x.ndim == k
            batch = x.reshape(1 if single else x.shape[0], -1)
        actions = self._model.predict(np.ascontiguousarray(batch), deterministic)
        if self.action_space.shape == ():  # Discrete: one whole number per observation
            actions = actions[:, 0].astype(np.int64)
        return (actions[0] if single else actions), None


def load_policy(run_dir: str | os.PathLike) -> Policy:
    """The model of a `twinbots train` run directory (its final model, else its newest
    checkpoint that loads: a damaged one is passed over, as `twinbots eval` does), or of a model
    directory itself, whichever algorithm trained it."""
    return Policy(run_dir)
