"""A policy leaves twinbots: `twinbots export` writes an ONNX graph that onnxruntime runs with
the same answers as the model itself, and training writes TensorBoard event files that
TensorBoard's own reader reads."""

from __future__ import annotations

import csv
import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

import twinbots
from test_policy import cli

ort = pytest.importorskip("onnxruntime")


def train(out: Path, *args: str) -> Path:
    exe = cli()
    if exe is None:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN) to train a model with")
    subprocess.run([exe, "train", *args, "--out", str(out)], check=True, capture_output=True)
    return out


@pytest.fixture(scope="module")
def cartpole_run(tmp_path_factory):
    """Discrete actions, raw observations."""
    out = tmp_path_factory.mktemp("export") / "cartpole"
    return train(out, "cartpole", "--timesteps", "4096", "--arenas", "4", "--seed", "3")


@pytest.fixture(scope="module")
def ur5e_run(tmp_path_factory):
    """Continuous actions in a box, normalised observations, periodic evaluations."""
    base = tmp_path_factory.mktemp("export")
    config = base / "short.toml"
    config.write_text("timesteps = 2048\narenas = 2\neval_every = 2\neval_episodes = 2\n"
                      "[ppo]\nn_steps = 256\nnormalize_observations = true\n")  # a [ppo] table replaces the defaults
    return train(base / "ur5e", "ur5e", "--config", str(config))


def export(run: Path, tmp_path: Path) -> Path:
    path = tmp_path / f"{run.name}.onnx"
    subprocess.run([cli(), "export", str(run), "--onnx", str(path)], check=True, capture_output=True)
    return path


def random_observations(n: int, dim: int, scale: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    obs = rng.uniform(-scale, scale, size=(n, dim)).astype(np.float32)
    obs[::97] *= 50  # some far out, past the normaliser's clip
    return obs


def onnx_actions(path: Path, obs: np.ndarray) -> np.ndarray:
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == ["obs"]
    assert [o.name for o in session.get_outputs()] == ["action"]
    return session.run(["action"], {"obs": obs})[0]


def test_onnxruntime_makes_the_models_discrete_choices(cartpole_run, tmp_path):
    path = export(cartpole_run, tmp_path)
    meta = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_modelmeta().custom_metadata_map
    assert meta["twinbots.robot"] == "cartpole" and meta["twinbots.task"] == "balance"
    assert json.loads(meta["twinbots.observation_names"]) == ["cart_x", "cart_velocity", "pole_angle", "pole_rate"]
    assert json.loads(meta["twinbots.action_space"]) == {"Discrete": {"n": 2}}
    assert float(meta["twinbots.control_period_s"]) == pytest.approx(0.032)
    obs = random_observations(1000, 4, 1.0, seed=1)
    actions = onnx_actions(path, obs)
    own, _ = twinbots.load_policy(cartpole_run).predict(obs, deterministic=True)
    assert actions.dtype == np.int64 and actions.shape == (1000,)
    np.testing.assert_array_equal(actions, own)
    assert 0 < own.sum() < 1000, "both choices occur"


def test_onnxruntime_gives_the_models_continuous_actions_with_normalisation_folded_in(ur5e_run, tmp_path):
    path = export(ur5e_run, tmp_path)
    meta = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).get_modelmeta().custom_metadata_map
    assert meta["twinbots.observation_normalization"] == "folded"
    obs = random_observations(1000, 26, 2.0, seed=2)
    actions = onnx_actions(path, obs)
    own, _ = twinbots.load_policy(ur5e_run).predict(obs, deterministic=True)
    assert actions.shape == (1000, 5) and actions.dtype == np.float32
    delta = np.abs(actions - own).max()
    print(f"onnxruntime vs twinbots, UR5e reach: max |delta| {delta:.2e}")
    assert delta <= 1e-5


@pytest.fixture(scope="module")
def keypoints_run(tmp_path_factory):
    """The camera reach's form: a camera image and the arm's own state, read through keypoints."""
    base = tmp_path_factory.mktemp("export")
    config = base / "keypoints.toml"
    config.write_text("timesteps = 128\narenas = 2\neval_episodes = 2\n"
                      "[pixels]\ncamera = \"iso\"\nwidth = 48\nheight = 40\n"
                      "state = [\"joint_positions\", \"tcp_position\"]\n"
                      "[ppo]\npolicy = \"keypoints\"\nshare_features_extractor = false\n"
                      "normalize_observations = false\n"
                      "n_steps = 64\nbatch_size = 64\n")
    return train(base / "ur5e-keypoints", "ur5e", "--config", str(config))


def test_onnxruntime_runs_a_keypoint_policy_as_the_model_does(keypoints_run, tmp_path):
    path = export(keypoints_run, tmp_path)
    image, state = 40 * 48 * 3, 6 + 3
    rng = np.random.default_rng(4)
    pixels = rng.integers(0, 256, size=(200, 40, 48, 3)).astype(np.float32)
    values = rng.uniform(-2.0, 2.0, size=(200, state)).astype(np.float32)
    # The graph reads flat rows (the image's values, then the state's); Python's policy a Dict.
    actions = onnx_actions(path, np.concatenate([pixels.reshape(200, image), values], axis=1))
    own, _ = twinbots.load_policy(keypoints_run).predict({"image": pixels, "state": values}, deterministic=True)
    assert actions.shape == own.shape == (200, 5)
    delta = np.abs(actions - own).max()
    print(f"onnxruntime vs twinbots, keypoints on a 48x40 image and 9 state values: max |delta| {delta:.2e}")
    assert delta <= 1e-4
    assert np.ptp(own, axis=0).max() > 1e-3, "the actions vary with the observation"


def scalars(run: Path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    accumulator = EventAccumulator(str(run), size_guidance={"scalars": 0})  # 0: keep every point
    accumulator.Reload()
    return accumulator


def rows(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def test_tensorboard_reads_every_update_of_a_training_run(cartpole_run):
    pytest.importorskip("tensorboard")
    board = scalars(cartpole_run)
    progress = rows(cartpole_run / "progress.csv")
    for tag in ["rollout/ep_len_mean", "train/loss", "train/policy_gradient_loss", "train/value_loss",
                "train/entropy_loss", "train/approx_kl", "train/clip_fraction", "train/learning_rate", "time/fps"]:
        points = board.Scalars(tag)
        assert [p.step for p in points] == [int(r["timesteps"]) for r in progress], tag
    kl = [p.value for p in board.Scalars("train/approx_kl")]
    np.testing.assert_allclose(kl, [float(r["approx_kl"]) for r in progress], rtol=1e-5)
    # Episode means exist from the first update with a finished episode on.
    with_episodes = [r for r in progress if math.isfinite(float(r["mean_reward"]))]
    rewards = board.Scalars("rollout/ep_rew_mean")
    assert len(rewards) == len(with_episodes) > 0
    np.testing.assert_allclose([p.value for p in rewards], [float(r["mean_reward"]) for r in with_episodes], rtol=1e-5)
    assert "rollout/success_rate" not in board.Tags()["scalars"], "the cart-pole reports no success"


def test_tensorboard_reads_the_task_figures_and_evaluations(ur5e_run):
    pytest.importorskip("tensorboard")
    board = scalars(ur5e_run)
    tags = board.Tags()["scalars"]
    progress = rows(ur5e_run / "progress.csv")
    evaluations = rows(ur5e_run / "evaluations.csv")
    assert len(board.Scalars("train/std")) == len(progress), "a Gaussian policy logs its σ"
    for figure in ["rollout/success_rate", "rollout/energy_j", "rollout/collision_events"]:
        assert figure in tags, tags
    for tag in ["eval/mean_reward", "eval/mean_ep_length", "eval/success_rate", "eval/energy_j"]:
        assert [p.step for p in board.Scalars(tag)] == [int(r["timesteps"]) for r in evaluations], tag


def test_a_resumed_run_shows_each_update_once_in_tensorboard(tmp_path):
    """The resumed process logs again what came after its checkpoint; TensorBoard drops the
    first process's points there (a SessionLog START), so every update is one point."""
    pytest.importorskip("tensorboard")
    # 13 updates of 4 × 32 steps; checkpoints every 4: the last one after update 12.
    run = train(tmp_path / "run", "cartpole", "--timesteps", "1664", "--arenas", "4", "--checkpoint-every", "4")
    subprocess.run([cli(), "train", "--resume", str(run)], check=True, capture_output=True)
    assert len(list(run.glob("events.out.tfevents.*"))) == 2
    progress = rows(run / "progress.csv")
    steps = [p.step for p in scalars(run).Scalars("train/loss")]
    assert steps == [int(r["timesteps"]) for r in progress] == list(range(128, 1665, 128))
