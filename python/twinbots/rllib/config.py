"""`ppo_config`: RLlib's PPO (new API stack) set up like `twinbots train` sets up its own PPO for
a robot: the robot's tuned hyperparameters (SB3's names, mapped below), the same 64-64 tanh
networks, and observation normalisation where the robot uses it."""

from __future__ import annotations

import math

import gymnasium as gym

from .. import _native
from .env import register_env


def _runner_callbacks():
    """Per-runner sample counts and every finished episode's return, length and success, as
    custom metrics (`result["env_runners"]["twinbots"]`)."""
    from ray.rllib.callbacks.callbacks import RLlibCallback

    class TwinbotsMetrics(RLlibCallback):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            # Return and length so far of episodes still running, by episode id: a sample holds
            # chunks of episodes (of `rollout_fragment_length` steps), not whole ones.
            self._running: dict[str, tuple[float, int]] = {}

        def on_sample_end(self, *, env_runner=None, metrics_logger=None, samples=(), **kwargs):
            steps = 0
            for chunk in samples:
                steps += len(chunk)
                ret, length = self._running.pop(chunk.id_, (0.0, 0))
                ret, length = ret + float(chunk.get_return()), length + len(chunk)
                if not chunk.is_done:
                    self._running[chunk.id_] = (ret, length)
                    continue
                # Every finished episode, not RLlib's means: the driver keeps the last 100
                # (RLlib's `episode_return_mean` covers only episodes finished in the iteration).
                metrics_logger.log_value(("twinbots", "episode_returns"), ret, reduce="item_series")
                metrics_logger.log_value(("twinbots", "episode_lengths"), float(length), reduce="item_series")
                info = chunk.get_infos(-1) or {}
                if "is_success" in info:
                    metrics_logger.log_value(("twinbots", "episode_successes"), float(info["is_success"]),
                                             reduce="item_series")
            metrics_logger.log_value(("twinbots", f"runner_{env_runner.worker_index}_steps"), steps, reduce="sum")

    return TwinbotsMetrics


def ppo_config(
    robot: str,
    task: str | None = None,
    env_runners: int = 2,
    envs_per_runner: int | None = None,
    seed: int = 0,
    timesteps: int | None = None,
):
    """A `ray.rllib.algorithms.ppo.PPOConfig` for `robot`'s `task` with `env_runners` processes
    of `envs_per_runner` arenas each (default: the robot's arena count spread over the runners).

    Mapping from the robot's PPO settings (SB3 names → RLlib): `n_steps` → rollout fragment
    length (per arena), so a train batch is n_steps × all arenas as in `twinbots train`;
    `batch_size` → `minibatch_size`; `n_epochs` → `num_epochs`; `gae_lambda` → `lambda_`;
    `clip_range` → `clip_param`; `ent_coef` → `entropy_coeff`; `vf_coef` → `vf_loss_coeff`;
    `max_grad_norm` → `grad_clip` (global norm); `linear_lr` → an lr schedule to 0 over
    `timesteps`. SB3 has no KL penalty and no value clipping, so neither does this."""
    from ray.rllib.algorithms.ppo import PPOConfig

    if env_runners < 0:
        raise ValueError(f"env_runners must be at least 0, got {env_runners}")
    defaults = _native.training_defaults(robot, task)
    ppo = defaults["ppo"]
    runners = max(env_runners, 1)
    if envs_per_runner is None:
        envs_per_runner = max(1, defaults["arenas"] // runners)
    if envs_per_runner < 1:
        raise ValueError(f"envs_per_runner must be at least 1, got {envs_per_runner}")
    timesteps = timesteps or defaults["timesteps"]
    lr = ppo["learning_rate"]
    schedule = [[0, lr], [timesteps, 0.0]] if ppo["linear_lr"] else lr
    model = {
        "fcnet_hiddens": list(ppo["hidden"]),
        "fcnet_activation": "tanh",
        "vf_share_layers": False,
        "head_fcnet_hiddens": [],
    }
    if defaults["action_space"]["kind"] == "box":
        # A state-independent log std, as twinbots' and SB3's Gaussian policies have.
        model["free_log_std"] = True
    config = (
        PPOConfig()
        .environment(register_env(robot, task))
        .env_runners(
            num_env_runners=env_runners,
            num_envs_per_env_runner=envs_per_runner,
            gym_env_vectorize_mode=gym.VectorizeMode.VECTOR_ENTRY_POINT,
            rollout_fragment_length=ppo["n_steps"],
            num_cpus_per_env_runner=1,
        )
        .training(
            train_batch_size_per_learner=ppo["n_steps"] * envs_per_runner * runners,
            minibatch_size=min(ppo["batch_size"], ppo["n_steps"] * envs_per_runner * runners),
            num_epochs=ppo["n_epochs"],
            lr=schedule,
            gamma=ppo["gamma"],
            lambda_=ppo["gae_lambda"],
            clip_param=ppo["clip_range"],
            entropy_coeff=ppo["ent_coef"],
            vf_loss_coeff=ppo["vf_coef"],
            vf_clip_param=math.inf,
            use_kl_loss=False,
            grad_clip=ppo["max_grad_norm"],
            grad_clip_by="global_norm",
        )
        .rl_module(model_config=model)
        .callbacks(_runner_callbacks())
        .debugging(seed=seed)
    )
    if ppo["normalize_observations"]:
        from ray.rllib.connectors.env_to_module import MeanStdFilter

        config = config.env_runners(env_to_module_connector=lambda env, spaces=None, device=None: MeanStdFilter())
    return config
