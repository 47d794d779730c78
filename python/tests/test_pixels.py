"""Camera images as observations (`obs="pixels"`, docs/pixels.md): the spaces SB3's CnnPolicy
recognises, the final frame of an ended episode, determinism, several cameras side by side,
bad settings, SB3's PPO with `CnnPolicy` training on them, and an image with the robot's own
state as a Dict (SB3's `MultiInputPolicy`)."""

from __future__ import annotations

import os

import numpy as np
import pytest
from gymnasium import spaces

import twinbots


def _pixel_envs(robot="cartpole", make=twinbots.make_vec, **kwargs):
    try:
        return make(robot, obs="pixels", **kwargs)
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


def test_more_cameras_lie_side_by_side_along_the_width():
    def first_images(pixels):
        envs = _pixel_envs(num_envs=2, seed=3, pixels={"width": 32, "height": 24, **pixels})
        obs, _ = envs.reset(seed=3)
        obs = np.stack([obs] + [envs.step(np.array([t % 2, 1]))[0] for t in range(5)])
        envs.close()
        return envs.single_observation_space, obs

    space, both = first_images({"camera": "side", "more_cameras": ["front"]})
    assert space == spaces.Box(0, 255, (24, 64, 3), np.uint8)
    _, side = first_images({"camera": "side"})
    _, front = first_images({"camera": "front"})
    np.testing.assert_array_equal(both[..., :32, :], side)
    np.testing.assert_array_equal(both[..., 32:, :], front)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"obs": "rgb"}, "obs must be 'state' or 'pixels'"),
        ({"obs": "state", "pixels": {"frames": 2}}, "pass obs='pixels'"),
        ({"obs": "pixels", "pixels": {"width": 0}}, "pixels.width = 0"),
        ({"obs": "pixels", "pixels": {"frames": 9}}, "pixels.frames = 9"),
        ({"obs": "pixels", "pixels": {"camera": "ceiling"}},
         "pixels.camera = \"ceiling\": must be one of side, front, iso, top"),
        ({"obs": "pixels", "pixels": {"more_cameras": ["front", "front"]}},
         "pixels.more_cameras: \"front\" is named twice"),
        ({"obs": "pixels", "pixels": {"colour": 3}}, "unknown field `colour`"),
        ({"obs": "pixels", "pixels": {"fov": 180}}, "pixels.fov = 180: must be in (0, 180) degrees"),
        ({"obs": "pixels", "pixels": {"fov": -5.0}}, "pixels.fov = -5: must be in (0, 180) degrees"),
        ({"obs": "pixels", "pixels": {"state": ["wrist"]}},
         "pixels.state: the task cartpole observes no 'wrist'; its terms: "),
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


def test_an_image_and_the_arms_own_state_are_a_dict_observation_sb3s_multi_input_policy_trains_on():
    sb3 = pytest.importorskip("stable_baselines3")
    from twinbots.sb3 import make_vec_env

    pixels = {"camera": "iso", "fov": 30, "width": 40, "height": 40, "state": ["joint_positions", "joint_velocities"]}
    envs = _pixel_envs("ur5e", num_envs=2, seed=0, pixels=pixels)
    space = envs.single_observation_space
    assert isinstance(space, spaces.Dict)
    assert space["image"] == spaces.Box(0, 255, (40, 40, 3), np.uint8) and space["state"].shape == (12,)
    plain = twinbots.make_vec("ur5e", num_envs=2, seed=0)
    (obs, _), (state, _) = envs.reset(seed=0), plain.reset(seed=0)
    for t in range(6):
        assert obs["image"].shape == (2, 40, 40, 3) and obs["image"].dtype == np.uint8 and obs["image"].std() > 0
        np.testing.assert_array_equal(obs["state"], state[:, :12], err_msg=f"step {t}: the arm's angles and speeds")
        assert space.contains({k: v[0] for k, v in obs.items()})
        action = np.full((2, 5), 0.3 * (-1) ** t, np.float32)
        obs, state = envs.step(action)[0], plain.step(action)[0]
    envs.close()
    plain.close()

    # One env through a whole (100-step) reach: the ended episode's last observation is a dict too.
    env = _pixel_envs("ur5e", make=twinbots.make, seed=1, pixels=pixels)
    obs, _ = env.reset(seed=1)
    for _ in range(100):
        obs, _, terminated, truncated, _ = env.step(np.zeros(5, np.float32))
        assert obs["image"].shape == (40, 40, 3) and obs["state"].shape == (12,)
        if terminated or truncated:
            break
    assert truncated, "the reach gives up after 100 steps"
    env.close()

    model = sb3.PPO("MultiInputPolicy", make_vec_env("ur5e", n_envs=2, seed=0, obs="pixels", pixels=pixels),
                    n_steps=16, batch_size=32, n_epochs=1, seed=0,
                    policy_kwargs={"features_extractor_kwargs": {"cnn_output_dim": 16}})
    assert type(model.policy.features_extractor).__name__ == "CombinedExtractor"
    model.learn(32)
