"""What a finished episode tells Python users: the extension's summary as info entries."""

from __future__ import annotations

import numpy as np


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
    `episode_info` per env (each key with an `_key` mask), built in one pass because that
    method costs tens of microseconds per env and key. With `final_obs`, SAME_STEP's
    `final_obs` and `final_info` too."""
    envs = [i for i, _, _ in ended]
    mask = np.zeros(num_envs, dtype=np.bool_)
    mask[envs] = True

    def column(values, dtype, where=envs):
        out = np.zeros(num_envs, dtype=dtype)
        out[where] = values
        return out

    infos: dict = {
        "episode": {
            "r": column([s["score"] for _, _, s in ended], np.float64),
            "l": column([s["length"] for _, _, s in ended], np.int64),
            "_r": mask,
            "_l": mask,
        },
        "_episode": mask,
    }
    with_goal = [(i, s["success"]) for i, _, s in ended if s["success"] is not None]
    if with_goal:
        where = [i for i, _ in with_goal]
        infos["is_success"] = column([bool(v) for _, v in with_goal], np.bool_, where)
        infos["_is_success"] = column(True, np.bool_, where)
    for field, prefix in (("metrics", ""), ("rewards", "reward/")):
        names = sorted({name for _, _, s in ended for name in s[field]})
        for name in names:
            where = [i for i, _, s in ended if name in s[field]]
            infos[prefix + name] = column([s[field][name] for i, _, s in ended if name in s[field]], np.float64, where)
            infos["_" + prefix + name] = column(True, np.bool_, where)
    if final_obs:
        finals = np.full(num_envs, None, dtype=object)
        for i, obs, _ in ended:
            finals[i] = obs
        infos["final_info"] = dict(infos)
        infos["final_obs"] = finals
        infos["_final_obs"] = mask
        infos["_final_info"] = mask
    return infos
