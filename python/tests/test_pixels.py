"""Camera images as observations (`obs="pixels"`, docs/pixels.md): the spaces SB3's CnnPolicy
recognises, the final frame of an ended episode, determinism, bad settings, and SB3's PPO with
`CnnPolicy` training on them."""

from __future__ import annotations

import os

import numpy as np
import pytest
from gymnasium import spaces

import twinbots


def _pixel_envs(**kwargs):
    try:
        return twinbots.make_vec("cartpole", obs="pixels", **kwargs)
    except RuntimeError as e:
        assert "adapter" in str(e)
        if os.environ.get("TWINBOTS_REQUIRE_ADAPTER", "0") not in ("", "0"):
            raise  # CI has one (as for the Rust render tests)
        pytest.skip(f"no graphics adapter here: {e}")


def _run(seed: int, steps: int):
    envs = _pixel_envs(num_envs=2, seed=seed, pixels={"frames": 2, "width": 48, "height": 40})
    obs, _ = envs.reset(seed=seed)
    frames, finals = [obs], []
    for t in range(steps):
        obs, _, terminated, truncated, infos = envs.step(np.array([t % 2, (t // 3) % 2]))
        frames.append(obs)
        if "final_obs" in infos:
            for i in np.flatnonzero(infos["_final_obs"]):
                finals.append((i, infos["final_obs"][i], obs[i]))
    envs.close()
    return envs, np.stack(frames), finals


def test_pixel_observations_are_uint8_images_with_final_frames_and_the_same_for_the_same_seed():
    envs, frames, finals = _run(seed=4, steps=60)
    assert envs.single_observation_space == spaces.Box(0, 255, (40, 48, 6), np.uint8)
    assert frames.shape == (61, 2, 40, 48, 6) and frames.dtype == np.uint8
    assert frames.std() > 0, "images with something in them"
    # Frames stack oldest first: the newer half of one step is the older half of the next.
    np.testing.assert_array_equal(frames[1, 0, :, :, 3:], frames[2, 0, :, :, :3])
    # A new episode starts with its first image repeated.
    np.testing.assert_array_equal(frames[0, :, :, :, :3], frames[0, :, :, :, 3:])
    assert finals, "an episode ended in 60 steps of bang-bang control"
    for _, final, first in finals:
        assert final.shape == (40, 48, 6) and final.dtype == np.uint8
        assert not np.array_equal(final, first), "the final frame is the ended episode's, not the next one's"
        np.testing.assert_array_equal(first[:, :, :3], first[:, :, 3:])
    _, again, _ = _run(seed=4, steps=60)
    np.testing.assert_array_equal(frames, again)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"obs": "rgb"}, "obs must be 'state' or 'pixels'"),
        ({"obs": "state", "pixels": {"frames": 2}}, "pass obs='pixels'"),
        ({"obs": "pixels", "pixels": {"width": 0}}, "pixels.width = 0"),
        ({"obs": "pixels", "pixels": {"frames": 9}}, "pixels.frames = 9"),
        ({"obs": "pixels", "pixels": {"camera": "ceiling"}}, "pixels.camera = \"ceiling\": must be one of side, front, iso, top"),
        ({"obs": "pixels", "pixels": {"colour": 3}}, "unknown field `colour`"),
        ({"obs": "pixels", "pixels": {"fov": 180}}, "pixels.fov = 180: must be in (0, 180) degrees"),
        ({"obs": "pixels", "pixels": {"fov": -5.0}}, "pixels.fov = -5: must be in (0, 180) degrees"),
    ],
)
def test_bad_pixel_settings_name_the_key(kwargs, message):
    with pytest.raises(ValueError, match=None) as e:
        twinbots.make_vec("cartpole", num_envs=1, seed=0, **kwargs)
    assert message in str(e.value)


def test_sb3_ppo_with_cnn_policy_trains_on_pixels():
    sb3 = pytest.importorskip("stable_baselines3")
    from twinbots.sb3 import make_vec_env

    try:
        env = make_vec_env("cartpole", n_envs=2, seed=0, obs="pixels", pixels={"width": 40, "height": 40})
    except RuntimeError as e:
        if os.environ.get("TWINBOTS_REQUIRE_ADAPTER", "0") not in ("", "0"):
            raise
        pytest.skip(f"no graphics adapter here: {e}")
    model = sb3.PPO("CnnPolicy", env, n_steps=32, batch_size=32, n_epochs=1, seed=0,
                    policy_kwargs={"features_extractor_kwargs": {"features_dim": 32}})
    assert type(model.policy.features_extractor).__name__ == "NatureCNN"
    before = [p.detach().clone() for p in model.policy.features_extractor.parameters()]
    model.learn(128)
    after = list(model.policy.features_extractor.parameters())
    assert any(not np.allclose(b.numpy(), a.detach().numpy()) for b, a in zip(before, after)), "the CNN learnt"
    obs = env.reset()
    assert obs.shape == (2, 40, 40, 3) and obs.dtype == np.uint8
    actions, _ = model.predict(obs, deterministic=True)
    assert actions.shape == (2,)
    assert len(model.ep_info_buffer) > 0, "episodes ended and were counted"
    env.close()
