"""Ray RLlib on the twins (issue 12): a local Ray with two env runners trains the cart-pole
twin; the policy is handed over to twinbots' own evaluation.

These tests need `ray[rllib]`, which pins gymnasium 1.2: `scripts/test-python` runs them in a
second venv. Without ray they skip, unless TWINBOTS_REQUIRE_RAY=1 (set there) makes that a
failure."""

import json
import logging
import os
import subprocess

import pytest

if os.environ.get("TWINBOTS_REQUIRE_RAY") != "1":
    pytest.importorskip("ray.rllib")

import ray

from twinbots.rllib import ppo_config, save_model
from twinbots.rllib.__main__ import main as rllib_main
from twinbots.rllib.train import RUNNER_ENV, EpisodeWindow, progress_row, runner_steps


@pytest.fixture
def local_ray():
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        logging_level=logging.ERROR,
        runtime_env=RUNNER_ENV,
    )
    yield
    ray.shutdown()


def test_two_env_runners_sample_the_twin_and_the_mean_return_rises(local_ray, tmp_path):
    algo = ppo_config("cartpole", env_runners=2, envs_per_runner=4, seed=0).build_algo()
    try:
        returns, steps, episodes = [], {}, EpisodeWindow(100)
        for i in range(120):
            result = algo.train()
            episodes.add(result)
            row = progress_row(result, i + 1, 1.0, episodes)
            if "mean_reward" in row:
                returns.append(row["mean_reward"])
            for runner, n in runner_steps(result).items():
                steps[runner] = steps.get(runner, 0) + n
        # Both remote runners (1 and 2) stepped their arenas; the driver's local runner does not sample.
        assert set(steps) == {1, 2}, steps
        assert min(steps.values()) > 1000, steps
        # A random cart-pole policy lasts ~22 steps. The mean is over the last 100 episodes, so
        # it trails the policy. Seeds 0-4 of this very run (2026-11-27), best of the last 5
        # iterations after 120 (30,720 steps): 219, 54, 225, 132, 27 (seed 4 learns nothing in
        # 200 iterations); seed 0 gives 219 on every run (the run is deterministic). So this is
        # a fixed-seed regression check, docs/benchmarks.md "Learning in CI".
        assert len(returns) >= 5
        assert returns[0] < 30, returns
        assert max(returns[-5:]) > 150, returns

        # Handover: the RLlib policy saved as a twinbots model acts like RLlib's module.
        import numpy as np
        import torch

        import twinbots

        run = tmp_path / "handover"
        run.mkdir()
        save_model(algo, run, "cartpole", seed=0, timesteps=1, episodes=1)
        policy = twinbots.load_policy(run / "model")
        module = algo.get_module()
        obs = np.random.default_rng(0).normal(size=(256, 4)).astype(np.float32)
        with torch.no_grad():
            logits = module.forward_inference({"obs": torch.from_numpy(obs)})["action_dist_inputs"].numpy()
        ours, _ = policy.predict(obs, deterministic=True)
        assert (ours == logits.argmax(axis=1)).mean() == 1.0
    finally:
        algo.stop()


def test_runners_on_a_second_node_train_on_when_that_node_is_lost():
    """RLlib on a two-node Ray cluster on this machine (`ray.cluster_utils.Cluster`: each node
    its own raylet and object store): the env runners are pinned to the worker node by a
    custom resource, step the twin there and train the cart-pole past a threshold; then that
    node is removed mid-run and a new one joins, and RLlib restarts both runners on it and
    trains on (docs/rllib.md, a cluster)."""
    import torch
    from ray.cluster_utils import Cluster

    store = 100 * 2**20
    cluster = Cluster(
        initialize_head=True, head_node_args={"num_cpus": 1, "object_store_memory": store, "include_dashboard": False}
    )
    algo = None
    try:
        first = cluster.add_node(num_cpus=2, resources={"twinbots_runners": 2}, object_store_memory=store)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, runtime_env=RUNNER_ENV, log_to_driver=False, logging_level=logging.ERROR)
        config = ppo_config("cartpole", env_runners=2, envs_per_runner=4, seed=0)
        config.env_runners(custom_resources_per_env_runner={"twinbots_runners": 1})
        config.fault_tolerance(restart_failed_env_runners=True)
        algo = config.build_algo()

        def runner_nodes():
            where = algo.env_runner_group.foreach_env_runner(
                lambda _: ray.get_runtime_context().get_node_id(), local_env_runner=False
            )
            return sorted(where)

        assert first.node_id != cluster.head_node.node_id
        assert runner_nodes() == [first.node_id] * 2
        episodes, returns = EpisodeWindow(100), []
        for i in range(150):
            result = algo.train()
            episodes.add(result)
            returns.append(progress_row(result, i + 1, 1.0, episodes).get("mean_reward", 0.0))
            if returns[-1] > 45:
                break
        # A random policy lasts ~22 steps; the window trails the policy.
        assert returns[0] < 30 and returns[-1] > 45, returns

        cluster.remove_node(first)
        second = cluster.add_node(num_cpus=2, resources={"twinbots_runners": 2}, object_store_memory=store)
        steps_after, weights = {}, None
        for _ in range(60):
            result = algo.train()
            steps = runner_steps(result)
            if weights is None and set(steps) == {1, 2}:
                weights = {k: v.clone() for k, v in algo.get_module().state_dict().items()}
            for runner, n in steps.items():
                steps_after[runner] = steps_after.get(runner, 0) + n
        # Both runners came back, on the new node, and sampled there; training went on.
        assert algo.env_runner_group.num_healthy_remote_workers() == 2
        assert algo.env_runner_group.num_remote_worker_restarts() >= 2
        assert runner_nodes() == [second.node_id] * 2
        assert set(steps_after) == {1, 2} and min(steps_after.values()) > 2000, steps_after
        # The learner went on updating the policy from the new node's samples. (Not the episode
        # window: a policy that balances ends few episodes, and the window holds ended ones.)
        now = algo.get_module().state_dict()
        assert weights is not None and any(not torch.equal(weights[k], now[k]) for k in now)
    finally:
        if algo is not None:
            algo.stop()
        ray.shutdown()
        cluster.shutdown()


def test_the_command_writes_a_run_that_twinbots_eval_reads(tmp_path):
    run = tmp_path / "run"
    # Starts (and stops) its own local Ray: the fixture's is not running in this test.
    assert rllib_main(["train", "cartpole", "--env-runners", "2", "--envs-per-runner", "4", "--timesteps", "3000",
                       "--out", str(run)]) == 0
    for name in ("config.toml", "progress.csv", "learning_curve.png", "model/model.json", "model/model.safetensors",
                 "rllib_checkpoint", "rllib_summary.json", "eval.json", "summary.json"):
        assert (run / name).exists(), name
    # Ended as every twinbots run ends (`twinbots::run::finish`): the final model evaluated.
    evaluation = json.loads((run / "eval.json").read_text())
    assert evaluation["episodes"] >= 1 and json.loads((run / "summary.json").read_text())["robot"] == "cartpole"
    summary = json.loads((run / "rllib_summary.json").read_text())
    assert summary["timesteps"] >= 3000 and set(summary["steps_per_runner"]) == {"1", "2"}
    rows = (run / "progress.csv").read_text().splitlines()
    assert rows[0].startswith("update,timesteps,episodes,mean_reward") and len(rows) == summary["iterations"] + 1

    binary = os.environ.get("TWINBOTS_BIN")
    if binary:
        out = subprocess.run([binary, "eval", str(run), "--episodes", "2"], capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        assert "cartpole: balance: 2 episodes" in out.stdout


def test_a_run_resumes_from_its_checkpoint_with_its_rows_cut_back_to_it(tmp_path):
    run = tmp_path / "run"
    train = ["train", "cartpole", "--env-runners", "1", "--envs-per-runner", "4", "--checkpoint-every", "2",
             "--out", str(run)]
    assert rllib_main(train + ["--timesteps", "2000"]) == 0
    state = json.loads((run / "rllib_checkpoint" / "twinbots_state.json").read_text())
    before = (run / "progress.csv").read_text().splitlines()
    assert int(float(before[-1].split(",")[1])) == state["timesteps"] >= 2000
    # As a kill would leave it: rows logged after the checkpoint (one cut short), budget left.
    with open(run / "progress.csv", "a") as f:
        f.write(f"{state['iteration'] + 1},{state['timesteps'] + 1000},1,2,3,4,5,6,7,8,9,10,11,12,13,0\n")
        f.write(f"{state['iteration'] + 2},{state['timesteps'] + 2000},1,2")
    args = json.loads((run / "rllib_args.json").read_text())
    (run / "rllib_args.json").write_text(json.dumps(args | {"timesteps": 4000}))

    assert rllib_main(["train", "--resume", str(run)]) == 0
    rows = [r.split(",") for r in (run / "progress.csv").read_text().splitlines()[1:]]
    updates, steps = [int(float(r[0])) for r in rows], [int(float(r[1])) for r in rows]
    assert updates == list(range(1, len(rows) + 1)), updates
    assert all(b > a for a, b in zip(steps, steps[1:])) and steps[-1] >= 4000, steps
    assert (run / "progress.csv").read_text().splitlines()[: len(before)] == before
    summary = json.loads((run / "rllib_summary.json").read_text())
    assert summary["iterations"] == len(rows) and summary["timesteps"] == steps[-1]
    assert rllib_main(["train", "cartpole", "--resume", str(run)]) == 2


def test_bad_arguments_are_clear_errors(capsys):
    assert rllib_main(["train", "no-such-robot", "--timesteps", "10"]) == 2
    assert "unknown robot" in capsys.readouterr().err.lower()
    with pytest.raises(ValueError, match="envs_per_runner"):
        ppo_config("cartpole", env_runners=1, envs_per_runner=0)
