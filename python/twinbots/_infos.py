"""What a finished episode tells Python users: the extension's summary as info entries."""

from __future__ import annotations

from . import _native


def episode_info(summary: dict) -> dict:
    """One env's info: Gymnasium's `RecordEpisodeStatistics` layout (`episode`: `r`, `l`) plus
    the task's own figures: `is_success` for tasks with a goal, each metric (e.g. `energy`), and
    each reward term's episode sum under `reward/<term>`."""
    info = {"episode": {"r": float(summary["score"]), "l": int(summary["length"])}}
    if summary["success"] is not None:
        info["is_success"] = bool(summary["success"])
    for name, value in summary["metrics"].items():
        info[name] = float(value)
    for term, value in summary["rewards"].items():
        info[f"reward/{term}"] = float(value)
    return info


def vector_infos(num_envs: int, ended: list, final_obs: bool) -> dict:
    """The infos of a vectorised step in which the episodes in `ended` (`(env, final_obs,
    summary)`) ended, in Gymnasium's vector layout: what `VectorEnv._add_info` builds from
    `episode_info` per env (each key with an `_key` mask), built in one pass in Rust because
    that method costs tens of microseconds per env and key (and numpy's small-array calls,
    building the same in Python, ≈ 66 µs a call). With `final_obs`, SAME_STEP's `final_obs`
    and `final_info` too."""
    return _native.vector_infos(num_envs, ended, final_obs)
