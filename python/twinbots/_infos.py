"""What a finished episode tells Python users: the extension's summary as info entries."""

from __future__ import annotations


def episode_info(summary: dict) -> dict:
    """Gymnasium's `RecordEpisodeStatistics` layout (`episode`: `r`, `l`) plus the task's own
    figures: `is_success` for tasks with a goal, each metric (e.g. `energy`), and each reward
    term's episode sum under `reward/<term>`."""
    info = {"episode": {"r": float(summary["score"]), "l": int(summary["length"])}}
    if summary["success"] is not None:
        info["is_success"] = bool(summary["success"])
    for name, value in summary["metrics"].items():
        info[name] = float(value)
    for term, value in summary["rewards"].items():
        info[f"reward/{term}"] = float(value)
    return info
