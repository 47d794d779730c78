"""Every registered robot and task through Gymnasium's and SB3's env checkers."""

import os
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gymnasium_check_env

import twinbots

IDS = sorted(twinbots.env_ids())


def test_every_robot_and_task_is_registered():
    robots = twinbots.robots()
    assert {r["name"] for r in robots} >= {"cartpole", "pioneer3at", "ur5e"}
    for robot in robots:
        assert f"twinbots/{robot['name']}-v0" in gym.registry
        for task, _ in robot["tasks"][1:]:
            assert f"twinbots/{robot['name']}-{task}-v0" in gym.registry


@pytest.mark.parametrize("env_id", IDS)
def test_gymnasium_check_env(env_id):
    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # bounds advice (e.g. a non-normalised action box) is not a failure
        gymnasium_check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_sb3_check_env(env_id):
    from stable_baselines3.common.env_checker import check_env

    env = gym.make(env_id)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        check_env(env.unwrapped, warn=False, skip_render_check=True)
    env.close()


def test_spaces_carry_the_tasks_bounds_and_dtypes():
    env = gym.make("twinbots/cartpole-v0")
    assert env.action_space == gym.spaces.Discrete(2)
    assert env.observation_space.dtype == np.float32
    assert env.observation_space.shape == (4,)
    arm = gym.make("twinbots/ur5e-v0")
    assert arm.action_space.dtype == np.float32
    assert (arm.action_space.low == -1).all() and (arm.action_space.high == 1).all()
    assert np.isfinite(arm.observation_space.low).any()
    obs, _ = arm.reset(seed=0)
    assert obs.dtype == np.float32 and obs in arm.observation_space


@pytest.mark.parametrize("env_id", IDS)
def test_reset_with_a_seed_is_reproducible(env_id):
    env = gym.make(env_id)
    runs = []
    for _ in range(2):
        obs, _ = env.reset(seed=7)
        env.action_space.seed(7)
        trajectory = [obs]
        for _ in range(30):
            obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            trajectory.append(np.append(obs, reward))
            if terminated or truncated:
                trajectory.append(env.reset()[0])
        runs.append(np.concatenate(trajectory))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_rgb_array_renders_or_says_why():
    try:
        env = gym.make("twinbots/cartpole-v0", render_mode="rgb_array", width=160, height=120)
    except RuntimeError as e:
        assert "adapter" in str(e)
        if os.environ.get("TWINBOTS_REQUIRE_ADAPTER", "0") not in ("", "0"):
            raise  # CI has one (as for the Rust render tests)
        pytest.skip(f"no graphics adapter here: {e}")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
    assert frame.std() > 0, "a frame with something in it"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gymnasium_check_env(env.unwrapped)  # with its render check
    envs = twinbots.make_vec("cartpole", num_envs=3, seed=0, render_mode="rgb_array", config={"visual": {}})
    envs.reset(seed=0)
    frames = envs.render()  # Gymnasium's vector convention: a tuple, one frame per env
    assert isinstance(frames, tuple) and len(frames) == 3
    assert all(f.shape == (480, 640, 3) and f.dtype == np.uint8 for f in frames)
    assert not np.array_equal(frames[0], frames[1]), "each env in its own look"
    batch = envs.render_all()
    assert batch.shape == (3, 480, 640, 3)
    np.testing.assert_array_equal(batch, np.stack(frames))
    # Tiles are what each env looks like: env 0's tile is the single renderer's frame of it, but
    # for a few pixels on triangle edges (a batched frame places tiles in clip space, a single
    # one by its viewport: a pixel centre on an edge may fall either side) and ±1 of rounding.
    differs = np.abs(batch[0].astype(int) - envs.arenas.render().astype(int)).max(axis=-1) > 1
    assert differs.sum() <= 30, f"{differs.sum()} pixels differ"
    envs.close()


def test_visual_randomization_gives_each_episode_a_seeded_look():
    def frames(config, seed):
        try:
            env = gym.make("twinbots/ur5e-v0", render_mode="rgb_array", width=96, height=72, config=config)
        except RuntimeError as e:
            if os.environ.get("TWINBOTS_REQUIRE_ADAPTER", "0") not in ("", "0"):
                raise
            pytest.skip(f"no graphics adapter here: {e}")
        out = []
        for episode in range(2):
            env.reset(seed=seed if episode == 0 else None)
            out.append(env.render())
        env.close()
        return out

    visual = {"visual": {"textures": ["plain", "checker"], "lights": [1, 2]}}
    first, second = frames(visual, 3)
    again = frames(visual, 3)
    np.testing.assert_array_equal(first, again[0])  # same seed, same look, same frame
    np.testing.assert_array_equal(second, again[1])
    assert not np.array_equal(first, second), "a new episode, a new look"
    plain = frames(None, 3)[0]
    assert not np.array_equal(first, plain), "randomized against the plain twin"
    with pytest.raises(ValueError, match="randomization.visual.field_of_view"):
        gym.make("twinbots/ur5e-v0", config={"visual": {"field_of_view": 120.0}})
