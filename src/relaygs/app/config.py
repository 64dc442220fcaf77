"""The composed Hydra config as a plain, resolved dict with every path made absolute (against
the launch folder, so every job shares the store and scene cache)."""

from __future__ import annotations

import copy
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from relaygs.errors import InputError, one_line

PATH_KEYS = ("paths.outputs", "paths.scenes", "artifacts.root", "scene.path")
"""Dotted keys holding file-system paths."""
OPTIONAL_PATHS = ("scene.path",)
"""Those of PATH_KEYS that may be null (left as is): no `scene.path` is a synthetic scene."""


def resolve_config(cfg: DictConfig | Mapping[str, Any], base_dir: Path) -> dict[str, Any]:
    """Interpolations resolved, `hydra` dropped, each of PATH_KEYS absolute (from `base_dir`);
    an unresolvable interpolation or a path that is no text is one line."""
    if isinstance(cfg, DictConfig):
        try:
            config = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
        except OmegaConfBaseException as error:  # e.g. relay.k=${nope}
            raise InputError(f"cannot resolve the config: {one_line(error)}") from error
    else:
        config = copy.deepcopy(dict(cfg))
    config.pop("hydra", None)
    for dotted in PATH_KEYS:
        *parents, leaf = dotted.split(".")
        section: Any = config
        for part in parents:
            section = section.get(part) if isinstance(section, dict) else None
        if not isinstance(section, dict):
            continue  # a missing section is reported where it is read
        if section.get(leaf) is None and dotted in OPTIONAL_PATHS:
            continue
        path = Path(_path_text(section.get(leaf), dotted)).expanduser()
        section[leaf] = str(path if path.is_absolute() else (Path(base_dir) / path).resolve())
    return config


def _path_text(value: Any, dotted: str) -> str:
    """A path setting as text: a non-empty string or a bare number; str() would turn `[a]` or
    null into a folder called "['a']" or "None"."""
    if isinstance(value, int) and not isinstance(value, bool):
        value = str(value)
    if not isinstance(value, str) or not value:
        raise InputError(f"{dotted}: expected a path (a non-empty string), got {value!r}")
    return value
