"""An RLlib-trained PPO policy as a twinbots model: RLlib's default PPO module (separate actor
and critic MLP encoders, linear heads) holds the same networks as twinbots' `ActorCritic`, so
its weights map one to one, and `twinbots eval`, `twinbots.load_policy` and the rest read it."""

from __future__ import annotations

import os

import numpy as np

from .. import _native


def _our_name(rllib_name: str, hidden_layers: int) -> str | None:
    """`encoder.actor_encoder.net.mlp.2.weight` → `pi.1.weight`, `pi.net.mlp.0.bias` →
    `pi.<hidden_layers>.bias` (the output layer), `pi.log_std` → `log_std`; None for RLlib's
    constants."""
    parts = rllib_name.split(".")
    if parts[0] == "encoder" and parts[2:4] == ["net", "mlp"]:
        net = {"actor_encoder": "pi", "critic_encoder": "vf"}[parts[1]]
        return f"{net}.{int(parts[4]) // 2}.{parts[5]}"  # Linear, tanh, Linear, tanh, …
    if parts[0] in ("pi", "vf") and parts[1:3] == ["net", "mlp"]:
        return f"{parts[0]}.{hidden_layers}.{parts[4]}"
    if "log_std" in rllib_name and "clip" not in rllib_name:
        return "log_std"
    return None


def _module_weights(module, hidden_layers: int) -> dict[str, np.ndarray]:
    weights = {}
    for name, tensor in module.state_dict().items():
        ours = _our_name(name, hidden_layers)
        if ours is not None:
            weights[ours] = tensor.detach().cpu().numpy().astype(np.float32).reshape(tuple(tensor.shape))
    return weights


def _observation_statistics(algo):
    """Mean, variance and count of RLlib's `MeanStdFilter` (synchronised on the local env
    runner), or None when observations are not normalised."""
    runner = algo.env_runner_group.local_env_runner
    for connector in getattr(runner._env_to_module, "connectors", []):
        if type(connector).__name__ == "MeanStdFilter":
            from ray.rllib.utils.filter import RunningStat

            state = next(iter(connector.get_state().values()))
            stat = RunningStat.from_state(state["running_stats"][0])
            return np.asarray(stat.mean, dtype=np.float64), np.asarray(stat.var, dtype=np.float64), float(stat.n)
    return None


def save_model(algo, run_dir: str | os.PathLike, robot: str, task: str | None = None, seed: int = 0, timesteps: int = 0,
               episodes: int = 0) -> None:
    """Writes `algo`'s current policy into `run_dir/model/` in twinbots' model format."""
    module = algo.learner_group._learner.module["default_policy"] if algo.learner_group.is_local else algo.get_module()
    hidden_layers = len(_native.training_defaults(robot)["ppo"]["hidden"])
    weights = _module_weights(module, hidden_layers)
    stats = _observation_statistics(algo)
    kwargs = {}
    if stats is not None:
        kwargs = {"obs_mean": list(stats[0]), "obs_var": list(stats[1]), "obs_count": stats[2]}
    _native.save_model(os.fspath(run_dir), robot, task, weights, seed, timesteps, episodes, **kwargs)
