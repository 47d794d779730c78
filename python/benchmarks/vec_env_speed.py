"""Steps per second of the cart-pole twin through the Python VectorEnv at 1, 8 and 64 envs,
against the same arenas stepped by a Rust loop (the Python layer's overhead), and Gymnasium's
MuJoCo InvertedPendulum-v5 (SyncVectorEnv) beside them.

    python benchmarks/vec_env_speed.py [--steps 2000] [--envs 1 8 64] [--block 20]

Env steps per second = vectorised steps × envs / s. Both sides step the same actions: a fixed
random sequence of pushes, cycled; auto-resets included. A shared VM's speed drifts by ±15 %
over seconds, so both sides live side by side in one process and take turns in blocks of
`--block` vector steps (milliseconds each), in alternating order: a drift hits both alike.
Each row: both sides' rates over all their blocks, the overhead of those totals, and the
quartiles of the overheads of the block pairs."""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import twinbots
from twinbots import _native


def timed_steps_per_second(envs, rows: list, steps: int) -> float:
    """Env steps/s of `steps` vector steps of `envs` (reset first), cycling through `rows` of
    actions; closes the envs. For MuJoCo, measured apart."""
    envs.reset(seed=0)
    start = time.perf_counter()
    for t in range(steps):
        envs.step(rows[t % len(rows)])
    elapsed = time.perf_counter() - start
    envs.close()
    return steps * envs.num_envs / elapsed


def interleaved(num_envs: int, actions: np.ndarray, steps: int, block: int):
    """(Rust env-steps/s, Python env-steps/s, overheads of the block pairs in %): `steps`
    vector steps on each side, in turns of `block`."""
    rust = _native.RustLoop("cartpole", num_envs, actions, 0)
    envs = twinbots.make_vec("cartpole", num_envs=num_envs, seed=0)
    envs.reset(seed=0)
    rows = [a.astype(np.int64) for a in actions]
    t = 0

    def python_block() -> float:
        nonlocal t
        start = time.perf_counter()
        for _ in range(block):
            envs.step(rows[t % len(rows)])
            t += 1
        return time.perf_counter() - start

    rust_s, python_s, overheads = 0.0, 0.0, []
    for pair in range(max(1, steps // block)):
        if pair % 2 == 0:
            r = rust.run(block)
            p = python_block()
        else:
            p = python_block()
            r = rust.run(block)
        rust_s += r
        python_s += p
        overheads.append(100.0 * (1.0 - r / p))
    envs.close()
    done = max(1, steps // block) * block * num_envs
    return done / rust_s, done / python_s, overheads


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
    parser.add_argument("--steps", type=int, default=2000,
                        help="vectorised steps per side at 8 envs (fewer at more envs)")
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 8, 64])
    parser.add_argument("--block", type=int, default=20, help="vectorised steps per turn")
    args = parser.parse_args()

    print(f"{'envs':>5} {'Rust loop':>12} {'Python VectorEnv':>17} {'overhead':>9} "
          f"{'block pairs (quartiles)':>24} {'MuJoCo InvPendulum-v5':>22}")
    for n in args.envs:
        steps = max(20 * args.block, args.steps // max(1, n // 8))  # about the same wall time per row
        rng = np.random.default_rng(0)
        actions = rng.integers(0, 2, size=(256, n)).astype(np.float32)
        rust, python, overheads = interleaved(n, actions, steps, args.block)
        mujoco = mujoco_steps_per_second(n, steps)
        mj = f"{mujoco:>22,.0f}" if mujoco else f"{'-':>22}"
        q1, q2, q3 = statistics.quantiles(overheads, n=4)
        quartiles = f"{q1:.1f} / {q2:.1f} / {q3:.1f}%"
        print(f"{n:>5} {rust:>12,.0f} {python:>17,.0f} {100.0 * (1.0 - python / rust):>8.1f}% {quartiles:>24} {mj}")


if __name__ == "__main__":
    main()
