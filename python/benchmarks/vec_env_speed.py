"""Steps per second of the cart-pole twin through the Python VectorEnv at 1, 8 and 64 envs,
against the same arenas stepped by a Rust loop (the Python layer's overhead), and Gymnasium's
MuJoCo InvertedPendulum-v5 (SyncVectorEnv) beside them.

    python benchmarks/vec_env_speed.py [--steps 1000] [--envs 1 8 64] [--pairs 9]

Env steps per second = vectorised steps × envs / s. Both sides step the same actions: a fixed
random sequence of pushes, cycled; auto-resets included. Each row: the medians of `--pairs`
back-to-back measurements of both sides, the median of the pairs' overheads and their range."""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import twinbots
from twinbots import _native


def timed_steps_per_second(envs, rows: list, steps: int) -> float:
    """Env steps/s of `steps` vector steps of `envs` (reset first), cycling through `rows` of
    actions; closes the envs. The same loop for every library measured."""
    envs.reset(seed=0)
    start = time.perf_counter()
    for t in range(steps):
        envs.step(rows[t % len(rows)])
    elapsed = time.perf_counter() - start
    envs.close()
    return steps * envs.num_envs / elapsed


def python_steps_per_second(num_envs: int, actions: np.ndarray, steps: int) -> float:
    envs = twinbots.make_vec("cartpole", num_envs=num_envs, seed=0)
    return timed_steps_per_second(envs, [a.astype(np.int64) for a in actions], steps)


def mujoco_steps_per_second(num_envs: int, steps: int) -> float | None:
    try:
        import gymnasium as gym

        envs = gym.make_vec("InvertedPendulum-v5", num_envs=num_envs, vectorization_mode="sync")
    except Exception as e:  # mujoco not installed
        print(f"  (MuJoCo InvertedPendulum-v5 unavailable: {e})")
        return None
    rng = np.random.default_rng(0)
    rows = [rng.uniform(-3, 3, size=(num_envs, 1)).astype(np.float32) for _ in range(256)]
    return timed_steps_per_second(envs, rows, steps)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=1000, help="vectorised steps per measurement")
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 8, 64])
    parser.add_argument("--pairs", type=int, default=9, help="Rust/Python measurement pairs per row")
    args = parser.parse_args()

    print(f"{'envs':>5} {'Rust loop':>12} {'Python VectorEnv':>17} {'overhead':>9} {'pairs':>14} {'MuJoCo InvPendulum-v5':>22}")
    for n in args.envs:
        steps = max(200, args.steps // max(1, n // 8))  # about the same wall time per row
        rng = np.random.default_rng(0)
        actions = rng.integers(0, 2, size=(256, n)).astype(np.float32)
        # A shared VM's speed drifts by ±15 % over seconds: each pair is measured back to back,
        # in alternating order (a drift hits both sides alike), and the row reports medians.
        rust, python, overheads = [], [], []
        for pair in range(args.pairs):
            if pair % 2 == 0:
                r = _native.rust_steps_per_second("cartpole", n, actions, steps, 0)
                p = python_steps_per_second(n, actions, steps)
            else:
                p = python_steps_per_second(n, actions, steps)
                r = _native.rust_steps_per_second("cartpole", n, actions, steps, 0)
            rust.append(r)
            python.append(p)
            overheads.append(100.0 * (1.0 - p / r))
        mujoco = mujoco_steps_per_second(n, steps)
        mj = f"{mujoco:>22,.0f}" if mujoco else f"{'-':>22}"
        spread = f"{min(overheads):.1f}…{max(overheads):.1f}%"
        print(f"{n:>5} {statistics.median(rust):>12,.0f} {statistics.median(python):>17,.0f} {statistics.median(overheads):>8.1f}% {spread:>14} {mj}")


if __name__ == "__main__":
    main()
