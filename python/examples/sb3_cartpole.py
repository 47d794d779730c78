"""Stable-Baselines3's PPO trains the cart-pole twin to the paper's criterion: the mean score of
the last 100 episodes above 1950.

    python examples/sb3_cartpole.py [--timesteps 2000000] [--envs 8] [--seed 0] [--save model.zip]

The settings are RL Zoo's for CartPole-v1 (scaled for 8 envs), with a longer horizon: an
episode here lasts up to 1951 steps."""

from __future__ import annotations

import argparse
from collections import deque

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from twinbots.sb3 import make_vec_env

SOLVED = 1950.0


class StopWhenSolved(BaseCallback):
    """Stops training once the last 100 episodes average above the criterion."""

    def __init__(self):
        super().__init__()
        self.scores: deque[float] = deque(maxlen=100)
        self.episodes = 0

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            if "episode" in info:
                self.scores.append(info["episode"]["r"])
                self.episodes += 1
                if self.episodes % 50 == 0:
                    print(f"{self.num_timesteps:>9} steps, {self.episodes:>5} episodes: "
                          f"last-100 mean {np.mean(self.scores):7.1f}", flush=True)
        return not (len(self.scores) == 100 and np.mean(self.scores) > SOLVED)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--timesteps", type=int, default=2_000_000)
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--save", help="where to save the SB3 model (.zip)")
    args = parser.parse_args()

    env = make_vec_env("cartpole", n_envs=args.envs, seed=args.seed)
    model = PPO("MlpPolicy", env, n_steps=256, batch_size=256, n_epochs=20, gae_lambda=0.8, gamma=0.98,
                learning_rate=1e-3, clip_range=0.2, ent_coef=0.0, seed=args.seed, device="cpu", verbose=0)
    stop = StopWhenSolved()
    model.learn(total_timesteps=args.timesteps, callback=stop)
    mean = float(np.mean(stop.scores)) if stop.scores else 0.0
    solved = len(stop.scores) == 100 and mean > SOLVED
    print(f"{'solved' if solved else 'not solved'}: mean score of the last {len(stop.scores)} episodes {mean:.1f} "
          f"after {model.num_timesteps} steps ({stop.episodes} episodes)")
    if args.save:
        model.save(args.save)
    raise SystemExit(0 if solved else 1)


if __name__ == "__main__":
    main()
