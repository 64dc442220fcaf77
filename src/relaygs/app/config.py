"""The composed Hydra config as a plain, resolved dict with every path made absolute.

Relative paths resolve against the directory the user launched from (Hydra's original cwd),
so the artifact store and scene cache are shared by every job whatever its working directory.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from relaygs.errors import InputError, one_line

PATH_KEYS = ("paths.outputs", "paths.scenes", "artifacts.root", "scene.path")
"""Dotted keys holding file-system paths (None is left as is)."""


def resolve_config(cfg: DictConfig | Mapping[str, Any], base_dir: Path) -> dict[str, Any]:
    """Interpolations resolved, `hydra` dropped, and each of PATH_KEYS absolute (relative ones
    taken from `base_dir`, `~` expanded); an interpolation that does not resolve is one line."""
    if isinstance(cfg, DictConfig):
        try:
            config = OmegaConf.to_container(cfg, resolve=True)
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
        if isinstance(section, dict) and section.get(leaf) is not None:
            path = Path(str(section[leaf])).expanduser()
            section[leaf] = str(path if path.is_absolute() else (Path(base_dir) / path).resolve())
    return config
