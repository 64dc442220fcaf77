"""In-stage checkpoints, so a stage killed mid-way resumes where it was, not at step 0: sealed
`<key>.ckpt/step-<n>/` folders (tensors and state.json) renamed in whole (docs/artifacts.md)."""

from __future__ import annotations

import json
import random
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file

from relaygs.model.guard import check_finite
from relaygs.pipeline.fsio import publish_dir, remove_tree, save_tensors
from relaygs.pipeline.integrity import CorruptArtifactError, check_seal, is_sealed, seal
from relaygs.pipeline.layout import TEMP_PREFIX, TENSORS_FILE, checkpoint_dir, make_temp_dir
from relaygs.pipeline.statecodec import decode_tree, encode_tree

STEP_PREFIX = "step-"
STATE_FILE = "state.json"


@dataclass
class TrainingState:
    """A resumable training state: `step` is the number of completed steps."""

    step: int
    tensors: dict[str, torch.Tensor]
    optimizers: dict[str, dict[str, Any]]
    rng: dict[str, Any]
    extras: dict[str, Any] = field(default_factory=dict)

    def restore_rng(self) -> None:
        """Put the saved python/numpy/torch(/CUDA) RNG states back in place."""
        random.setstate(self.rng["python"])
        np.random.set_state(self.rng["numpy"])
        torch.set_rng_state(self.rng["torch"])
        if "cuda" in self.rng and torch.cuda.is_available():
            torch.cuda.set_rng_state_all(self.rng["cuda"])


class StageCheckpointer:
    """Saves and loads the in-stage checkpoints of one artifact build."""

    def __init__(
        self, store_root: Path | str, stage: str, key: str, every_n_steps: int, keep_last: int = 1
    ) -> None:
        """Checkpoints of artifact `key` of `stage` every `every_n_steps` (>= 1, as
        `train.checkpoint_every` is checked) steps, the newest `keep_last` of them kept."""
        self.folder = checkpoint_dir(Path(store_root).expanduser().resolve(), stage, key)
        self.stage = stage
        self.every_n_steps = every_n_steps
        self.keep_last = keep_last

    def due(self, step: int) -> bool:
        """True when a checkpoint should be written after `step` completed steps."""
        return step > 0 and step % self.every_n_steps == 0

    def latest_due(self, step: int) -> int:
        """The last step at or before `step` after which a checkpoint was due (0: none yet)."""
        return step - step % self.every_n_steps

    def save(
        self,
        step: int,
        tensors: Mapping[str, torch.Tensor],
        optimizers: Mapping[str, torch.optim.Optimizer] | None = None,
        extras: Mapping[str, Any] | None = None,
    ) -> Path:
        """Write a checkpoint after `step` completed steps (RNG captured now); a non-finite
        tensor anywhere in it raises DivergenceError naming it before anything is written."""
        stored: dict[str, torch.Tensor] = {}
        places: dict[str, str] = {}
        optimizer_states = {name: opt.state_dict() for name, opt in (optimizers or {}).items()}
        skeleton = {
            "step": step,
            "tensors": encode_tree(dict(tensors), stored, "model.", "tensors", places),
            "optimizers": encode_tree(optimizer_states, stored, "optim.", "optimizers", places),
            "rng": encode_tree(capture_rng_state(), stored, "rng.", "rng"),
            "extras": encode_tree(dict(extras or {}), stored, "extra.", "extras", places),
        }
        check_finite(self.stage, step, {places[name]: stored[name] for name in places})
        self._remove_stale_temps()
        temp = make_temp_dir(self.folder, f"{STEP_PREFIX}{step}")
        try:
            save_tensors(stored, temp / TENSORS_FILE)
            (temp / STATE_FILE).write_text(json.dumps(skeleton, allow_nan=False), encoding="utf-8")
            seal(temp)
            final = self.folder / f"{STEP_PREFIX}{step:012d}"
            publish_dir(temp, final)
        finally:
            remove_tree(temp)
        for old in self._step_dirs()[self.keep_last :]:
            remove_tree(old)
        return final

    def load(self) -> TrainingState | None:
        """The newest intact checkpoint, or None when there is none (a damaged one is
        skipped with a warning, falling back to an older one or to a fresh start)."""
        for folder in self._step_dirs():
            try:
                check_seal(folder)
                return _read_state(folder)
            except CorruptArtifactError as error:
                warnings.warn(f"ignoring damaged checkpoint: {error}", stacklevel=2)
        return None

    def _step_dirs(self) -> list[Path]:
        """Sealed step folders, newest first."""
        if not self.folder.is_dir():
            return []
        folders = [
            path
            for path in self.folder.iterdir()
            if path.name.startswith(STEP_PREFIX) and path.is_dir() and is_sealed(path)
        ]
        return sorted(folders, key=lambda path: int(path.name[len(STEP_PREFIX) :]), reverse=True)

    def _remove_stale_temps(self) -> None:
        """Drop temp folders a killed writer left (only the lock holder writes here)."""
        if self.folder.is_dir():
            for path in self.folder.iterdir():
                if path.name.startswith(TEMP_PREFIX):
                    remove_tree(path)


def _read_state(folder: Path) -> TrainingState:
    """Decode one checkpoint folder whose seal has been checked."""
    try:
        stored = load_file(str(folder / TENSORS_FILE))
        skeleton = json.loads((folder / STATE_FILE).read_text(encoding="utf-8"))
        return TrainingState(
            step=int(skeleton["step"]),
            tensors=decode_tree(skeleton["tensors"], stored),
            optimizers=decode_tree(skeleton["optimizers"], stored),
            rng=decode_tree(skeleton["rng"], stored),
            extras=decode_tree(skeleton["extras"], stored),
        )
    except (OSError, ValueError, KeyError, TypeError, SafetensorError) as error:
        raise CorruptArtifactError(f"{folder}: unreadable checkpoint ({error})") from error


def capture_rng_state() -> dict[str, Any]:
    """Snapshot of every global RNG a training loop may draw from."""
    state: dict[str, Any] = {
        "python": random.getstate(),
        "numpy": np.random.get_state(legacy=False),
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state
