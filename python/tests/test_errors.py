"""Mistakes come back as Python exceptions that say what is wrong, never a crash."""

import gymnasium as gym
import numpy as np
import pytest

import twinbots


def test_unknown_robot_lists_the_known_ones():
    with pytest.raises(ValueError, match="unknown robot 'nope'.*cartpole"):
        twinbots.make_vec("nope")
    with pytest.raises(gym.error.Error):
        gym.make("twinbots/nope-v0")


def test_unknown_task_lists_the_robots_tasks():
    with pytest.raises(ValueError, match="no task 'fly'.*balance"):
        twinbots.make_vec("cartpole", task="fly")


def test_unsupported_pattern():
    with pytest.raises(ValueError, match="pattern"):
        twinbots.make_vec("cartpole", pattern=3)
    with pytest.raises(ValueError, match="num_envs"):
        twinbots.make_vec("cartpole", num_envs=0)


@pytest.fixture
def envs():
    e = twinbots.make_vec("cartpole", num_envs=2, seed=0)
    e.reset(seed=0)
    return e


def test_bad_action_shape(envs):
    with pytest.raises(ValueError, match="shape"):
        envs.step(np.array([0, 1, 0]))


def test_bad_action_dtype(envs):
    with pytest.raises(ValueError, match="dtype"):
        envs.step(np.array(["left", "right"]))
    with pytest.raises(ValueError, match="whole numbers"):
        envs.step(np.array([0.5, 1.0]))
    with pytest.raises(ValueError, match="out of"):
        envs.step(np.array([0, 2]))


def test_nan_action():
    arm = twinbots.make_vec("ur5e", num_envs=2, seed=0)
    arm.reset(seed=0)
    actions = np.zeros((2, arm.single_action_space.shape[0]), dtype=np.float32)
    actions[1, 2] = np.nan
    with pytest.raises(ValueError, match="(?i)env 1.*nan"):
        arm.step(actions)


def test_single_env_errors():
    env = gym.make("twinbots/cartpole-v0")
    with pytest.raises(gym.error.ResetNeeded):
        env.step(0)
    env.reset(seed=0)
    with pytest.raises(ValueError):
        env.step(np.array([0, 1]))
    while True:
        _, _, terminated, truncated, _ = env.step(1)
        if terminated or truncated:
            break
    with pytest.raises(RuntimeError, match="reset"):
        env.unwrapped.step(1)


def test_stepping_a_closed_env(envs):
    envs.close()
    with pytest.raises(RuntimeError, match="closed"):
        envs.step(np.array([0, 1]))
    with pytest.raises(RuntimeError, match="closed"):
        envs.reset()


def test_render_without_render_mode_is_none(envs):
    assert envs.render() is None


def test_another_thread_gets_a_runtime_error(envs):
    import threading

    caught = []

    def step():
        try:
            envs.step(np.array([0, 1]))
        except BaseException as e:  # noqa: BLE001 - the point is which exception arrives
            caught.append(e)

    t = threading.Thread(target=step)
    t.start()
    t.join()
    assert len(caught) == 1 and type(caught[0]) is RuntimeError and "thread" in str(caught[0])
    envs.step(np.array([0, 1]))  # still fine on its own thread
