"""The vectorised env: spaces, autoreset modes, infos, determinism."""

import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, VectorEnv

import twinbots


def run(envs, steps, seed=3):
    obs, _ = envs.reset(seed=seed)
    envs.action_space.seed(seed)
    out = [obs.copy()]
    for _ in range(steps):
        obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())
        out += [obs.copy(), rewards, terminated, truncated]
    return out


def test_make_vec_is_a_vector_env_with_batched_spaces():
    envs = twinbots.make_vec("cartpole", num_envs=4, seed=0)
    assert isinstance(envs, VectorEnv)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert envs.observation_space.shape == (4, 4)
    obs, info = envs.reset(seed=0)
    assert obs.shape == (4, 4) and obs.dtype == np.float32 and info == {}
    assert obs in envs.observation_space
    obs, rewards, terminated, truncated, _ = envs.step(envs.action_space.sample())
    assert rewards.shape == (4,) and terminated.dtype == np.bool_ and truncated.dtype == np.bool_
    envs.close()


def test_same_seed_same_trajectories():
    a = run(twinbots.make_vec("cartpole", num_envs=3), 200)
    b = run(twinbots.make_vec("cartpole", num_envs=3), 200)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    c = run(twinbots.make_vec("cartpole", num_envs=3), 200, seed=4)
    assert not all(np.array_equal(x, y) for x, y in zip(a, c))


def test_same_step_autoreset_reports_the_finished_episode():
    envs = twinbots.make_vec("cartpole", num_envs=2, seed=1)
    envs.reset(seed=1)
    for _ in range(500):
        obs, rewards, terminated, truncated, infos = envs.step(np.array([1, 1]))
        if "final_obs" in infos:
            break
    else:
        pytest.fail("pushing right always must drop the pole")
    done = terminated | truncated
    np.testing.assert_array_equal(infos["_final_obs"], done)
    i = int(np.flatnonzero(done)[0])
    assert infos["final_obs"][i].shape == (4,) and not np.array_equal(infos["final_obs"][i], obs[i])
    assert infos["_episode"][i] and infos["episode"]["l"][i] > 0
    assert infos["final_info"]["episode"]["r"][i] == infos["episode"]["r"][i]


def test_next_step_autoreset_ignores_the_action_of_the_restart_step():
    def until_end(actions_after):
        envs = twinbots.make_vec("cartpole", num_envs=1, seed=2, autoreset_mode="NEXT_STEP")
        assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
        envs.reset(seed=2)
        while True:
            obs, r, term, trunc, infos = envs.step(np.array([0]))
            if term[0] or trunc[0]:
                break
        last = obs.copy()
        assert infos["_episode"][0] and "final_obs" not in infos
        restart = envs.step(np.array([actions_after]))
        return last, restart

    last_a, (obs_a, r_a, term_a, trunc_a, _) = until_end(0)
    last_b, (obs_b, r_b, term_b, trunc_b, _) = until_end(1)
    np.testing.assert_array_equal(last_a, last_b)
    assert not np.array_equal(obs_a, last_a), "the restart step shows the next episode's start"
    np.testing.assert_array_equal(obs_a, obs_b)  # whatever the action, the same start
    assert r_a[0] == 0 and not term_a[0] and not trunc_a[0]


def test_episode_figures_of_a_goal_task():
    envs = twinbots.make_vec("ur5e", num_envs=2, seed=0)
    envs.reset(seed=0)
    still = np.zeros((2, envs.single_action_space.shape[0]), dtype=np.float32)
    for _ in range(2000):
        _, _, terminated, truncated, infos = envs.step(still)
        if "episode" in infos:
            break
    else:
        pytest.fail("a reach episode ends within its time limit")
    done = terminated | truncated
    np.testing.assert_array_equal(infos["_is_success"], done)
    assert not infos["is_success"][done].any(), "an arm that does not move reaches nothing"
    terms = [k for k in infos if k.startswith("reward/")]
    assert sorted(terms) == sorted(f"reward/{t}" for t in envs.task["reward_terms"])
    total = sum(infos[k] for k in terms)
    np.testing.assert_allclose(total[done], infos["episode"]["r"][done], rtol=1e-4, atol=1e-3)


def test_randomization_config():
    plain = run(twinbots.make_vec("cartpole", num_envs=2), 50)
    noisy = run(twinbots.make_vec("cartpole", num_envs=2, config={"sensor_noise": 0.01}), 50)
    assert not all(np.array_equal(x, y) for x, y in zip(plain, noisy))
    again = run(twinbots.make_vec("cartpole", num_envs=2, config="[randomization]\nsensor_noise = 0.01\n"), 50)
    for x, y in zip(noisy, again):
        np.testing.assert_array_equal(x, y)
    with pytest.raises(ValueError, match="randomization"):
        twinbots.make_vec("cartpole", config={"no_such_setting": 1.0})


def test_pattern_2_runs_its_own_deterministic_trajectory():
    """Under pattern 2 the supervisor hears the slave robot over a radio, a step late: the same
    seed and actions give the same trajectory again, and another one than pattern 1's."""

    def trajectory(pattern):
        envs = twinbots.make_vec("cartpole", num_envs=2, seed=0, pattern=pattern)
        obs, _ = envs.reset(seed=0)
        seen = [obs.copy()]
        for _ in range(8):
            obs, rewards, terminated, truncated, _ = envs.step(np.array([1, 1]))
            assert obs.shape == (2, 4) and np.isfinite(obs).all()
            assert (rewards == 1.0).all() and not terminated.any() and not truncated.any()
            seen.append(obs.copy())
        envs.close()
        return np.array(seen)

    radio = trajectory(2)
    assert np.array_equal(radio, trajectory(2))
    assert not np.allclose(radio, trajectory(1)), "the radio delays what the supervisor hears and the slave does"


def test_infos_match_gymnasiums_own_layout():
    """The one-pass info builder gives what `VectorEnv._add_info` builds env by env."""
    from twinbots._infos import episode_info, vector_infos

    ended = [
        (1, np.ones(3, np.float32),
         {"score": 2.5, "length": 7, "success": True, "metrics": {"energy": 1.0}, "rewards": {"alive": 2.5}}),
        (3, np.zeros(3, np.float32),
         {"score": -1.0, "length": 9, "success": False, "metrics": {}, "rewards": {"alive": -1.0}}),
    ]
    envs = twinbots.make_vec("cartpole", num_envs=4, seed=0)
    expected = {}
    for i, final_obs, summary in ended:
        info = episode_info(summary)
        expected = envs._add_info(expected, {"final_obs": final_obs, "final_info": info, **info}, i)
    got = vector_infos(4, ended, final_obs=True)

    def same(a, b):
        assert set(a) == set(b)
        for k in a:
            if isinstance(a[k], dict):
                same(a[k], b[k])
            elif a[k].dtype == object:
                assert all((x is None and y is None) or np.array_equal(x, y) for x, y in zip(a[k], b[k]))
            else:
                np.testing.assert_array_equal(a[k], b[k])
                assert a[k].dtype == b[k].dtype, k

    same(got, expected)


def test_gymnasium_make_vec_uses_the_rust_arenas():
    import gymnasium as gym

    envs = gym.make_vec("twinbots/cartpole-v0", num_envs=3, vectorization_mode="vector_entry_point", seed=1)
    assert isinstance(envs, twinbots.TwinbotsVectorEnv) and envs.num_envs == 3
    assert envs.reset(seed=1)[0].shape == (3, 4)
