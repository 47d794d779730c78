"""Gymnasium ids for every built-in robot and task: `twinbots/<robot>-v0` is the robot's main
task (the one `twinbots train` learns), `twinbots/<robot>-<task>-v0` each other task."""

from __future__ import annotations

import gymnasium as gym

from . import _native


def env_ids() -> dict[str, tuple[str, str]]:
    """`{id: (robot, task)}` for every registered robot and task."""
    ids = {}
    for robot in _native.robots():
        for k, (task, _description) in enumerate(robot["tasks"]):
            suffix = "" if k == 0 else f"-{task}"
            ids[f"twinbots/{robot['name']}{suffix}-v0"] = (robot["name"], task)
    return ids


def register_all() -> None:
    for env_id, (robot, task) in env_ids().items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="twinbots.env:TwinbotsEnv",
            vector_entry_point="twinbots.vector:TwinbotsVectorEnv",
            kwargs={"robot": robot, "task": task},
            # The task's own time limit truncates; Gymnasium adds no TimeLimit.
            max_episode_steps=None,
            disable_env_checker=False,
        )
