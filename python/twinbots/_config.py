"""`config=`: domain randomization as in `twinbots train --config` (its `[randomization]`
table), given as a TOML file, TOML text, or a dict of the table's entries (sub-tables as
dicts: `{"visual": {"lights": [1, 2]}}`)."""

from __future__ import annotations

import json
import os
from typing import Union

Config = Union[None, str, os.PathLike, dict]


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, (str, os.PathLike)):
        return json.dumps(os.fspath(v))  # a TOML basic string: JSON's escapes are TOML's
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise ValueError(f"config: unsupported value {v!r} (numbers, strings, lists and tables only)")


def toml_keys(table: dict) -> str:
    """A table's entries as TOML lines `key = value`."""
    return "".join(f"{k} = {_toml_value(v)}\n" for k, v in table.items())


def config_text(config: Config) -> str | None:
    """TOML text for the extension, or None."""
    if config is None:
        return None
    if isinstance(config, dict):
        table = config.get("randomization", config)
        if not isinstance(table, dict):
            raise ValueError("config: 'randomization' must be a table of settings")
        return "[randomization]\n" + toml_keys(table)
    if isinstance(config, os.PathLike) or (isinstance(config, str) and "\n" not in config and "=" not in config):
        try:
            with open(config, encoding="utf-8") as f:
                return f.read()
        except OSError as e:
            raise ValueError(f"config: cannot read {config}: {e}") from e
    if isinstance(config, str):
        return config
    raise ValueError(f"config must be a TOML file, TOML text or a dict, got {type(config).__name__}")
