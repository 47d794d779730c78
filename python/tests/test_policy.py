"""`load_policy` acts as the Rust side does: the same episodes as `twinbots eval`."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import twinbots


def cli() -> str | None:
    """The `twinbots` CLI of this build (scripts/test-python points TWINBOTS_BIN at it)."""
    return os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    exe = cli()
    if exe is None:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN) to train a model with")
    out = tmp_path_factory.mktemp("run") / "cartpole"
    subprocess.run([exe, "train", "cartpole", "--timesteps", "4096", "--arenas", "4", "--seed", "11",
                    "--out", str(out)],
                   check=True, capture_output=True)
    return out


def test_predict_matches_twinbots_eval(run_dir):
    exe = cli()
    report = subprocess.run([exe, "eval", str(run_dir), "--episodes", "3", "--arenas", "1"],
                            check=True, capture_output=True, text=True).stdout
    rust_mean = float(re.search(r"score ([0-9.]+) ±", report).group(1))
    rust_length = float(re.search(r"mean length ([0-9.]+)", report).group(1))

    policy = twinbots.load_policy(run_dir)
    assert policy.action_space == twinbots.make("cartpole").action_space
    config = (Path(run_dir) / "config.toml").read_text()
    seed = int(re.search(r"^seed = (\d+)", config, re.M).group(1)) + 2_000_003  # eval's seed
    envs = twinbots.make_vec("cartpole", num_envs=1, seed=seed)
    obs, _ = envs.reset(seed=seed)
    scores, lengths = [], []
    while len(scores) < 3:
        actions, _ = policy.predict(obs, deterministic=True)
        obs, _, _, _, infos = envs.step(actions)
        if "episode" in infos:
            scores.append(infos["episode"]["r"][0])
            lengths.append(infos["episode"]["l"][0])
    assert np.mean(lengths) == pytest.approx(rust_length, abs=0.05)
    assert np.mean(scores) == pytest.approx(rust_mean, abs=0.05)


def test_predict_single_and_batch(run_dir):
    policy = twinbots.load_policy(run_dir)
    obs = np.zeros((5, 4), dtype=np.float32)
    batch, state = policy.predict(obs)
    assert state is None and batch.shape == (5,) and batch.dtype == np.int64
    single, _ = policy.predict(obs[0])
    assert single == batch[0]
    with pytest.raises(ValueError, match="4"):
        policy.predict(np.zeros((2, 3), dtype=np.float32))


def test_missing_model_is_a_value_error(tmp_path):
    with pytest.raises(ValueError, match="no model"):
        twinbots.load_policy(tmp_path)


def test_a_sac_run_loads_and_a_damaged_newest_checkpoint_is_passed_over_as_eval_does(tmp_path):
    """Any algorithm of the table loads; the checkpoint chosen is the one `twinbots eval` takes."""
    exe = cli()
    if exe is None:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN) to train a model with")
    config = tmp_path / "sac.toml"
    config.write_text("eval_episodes = 2\ncheckpoint_every = 1\n"
                      "[sac]\nlearning_starts = 100\nlog_interval = 100\nbatch_size = 32\n")
    run = tmp_path / "run"
    subprocess.run([exe, "train", "ur5e", "--algo", "sac", "--timesteps", "300", "--arenas", "1",
                    "--config", str(config), "--out", str(run)],
                   check=True, capture_output=True)
    checkpoints = sorted((run / "checkpoints").iterdir())
    assert len(checkpoints) >= 2, checkpoints
    # Without its final model, the run's newest checkpoint is next; damage it.
    shutil.rmtree(run / "model")
    (checkpoints[-1] / "model.safetensors").write_bytes(b"not a tensor file")
    policy = twinbots.load_policy(run)
    assert policy.algorithm == "SAC"
    assert Path(policy.path) == checkpoints[-2]
    assert policy.action_space == twinbots.make("ur5e").action_space
    report = subprocess.run([exe, "eval", str(run), "--episodes", "1", "--arenas", "1"], capture_output=True, text=True)
    assert report.returncode == 0, report.stderr
    assert checkpoints[-1].name in report.stderr and "unusable" in report.stderr
    obs = np.zeros((3, policy.observation_space.shape[0]), dtype=np.float32)
    first, _ = policy.predict(obs, deterministic=True)
    again, _ = policy.predict(obs, deterministic=True)
    assert first.shape == (3, policy.action_space.shape[0]) and np.array_equal(first, again)
