"""The model every stage hands on, and its artifact form (docs/method.md, Artifacts)."""

from __future__ import annotations

import dataclasses
import math
import textwrap
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

import torch
from torch import Tensor

from relaygs.errors import InputError, one_line
from relaygs.field import ColorAffine, DeformationField
from relaygs.model import GaussianSet
from relaygs.pipeline.artifact import Artifact
from relaygs.train.segment_plan import SegmentPlan

SEGMENT = "segment"
GAMMA = "gamma"
FIELD_PREFIX = "field."
AFFINE_PREFIX = "affine."
DECOUPLE = "decouple"
EPS2D_BEFORE_RECORDED = 0.3  # what every model was trained and rendered with before meta held it


@dataclass
class SceneModel:
    """Background + foreground sets, their segments, and optional motion modules; `eps2d` is the
    screen-space blur (px²) it was trained with and renders with, `antialiased` whether that blur
    keeps each splat's screen integral; `affine_cameras` lists the train camera ids in
    ColorAffine row order."""

    stage: str
    background: GaussianSet
    foreground: GaussianSet
    segments: SegmentPlan
    eps2d: float
    antialiased: bool = False
    field: DeformationField | None = None
    field_settings: dict[str, Any] | None = None
    affine: ColorAffine | None = None
    affine_cameras: list[int] = dataclasses.field(default_factory=list)

    def blur(self) -> dict[str, Any]:
        """The screen blur it renders with, as the keyword arguments of `splat`."""
        return {"eps2d": self.eps2d, "antialiased": self.antialiased}

    @property
    def num_frames(self) -> int:
        return self.segments.num_frames

    @property
    def num_segments(self) -> int:
        """S, the number of segments (ceil(T / k) for uniform ones)."""
        return self.segments.count

    def gaussian_counts(self) -> dict[str, int]:
        """The Gaussian counts every stage's metrics report."""
        n_bg, n_fg = len(self.background), len(self.foreground)
        return {"num_gaussians": n_bg + n_fg, "num_bg": n_bg, "num_fg": n_fg}

    def foreground_rows(self, frame: int) -> Tensor:
        """Indices of the foreground rows rendered at `frame`: a decouple model shows its
        foreground at frame 0 only, any other the copy of the segment holding `frame` and the
        frame's own patch (rows tagged S + frame, see `frame_patch_tag`)."""
        segments = self.foreground.buffers[SEGMENT]
        if self.stage == DECOUPLE:
            if frame == 0:
                return torch.arange(segments.shape[0], device=segments.device)
            return torch.zeros(0, dtype=torch.int64, device=segments.device)
        shown = (segments == self.segments.segment_of(frame)) | (
            segments == self.frame_patch_tag(frame)
        )
        return shown.nonzero().squeeze(1)

    def frame_patch_tag(self, frame: int) -> int:
        """The segment tag of rows shown at `frame` alone: S + frame, past every segment's."""
        return self.num_segments + frame

    def in_frame_patches(self) -> Tensor:
        """[N_fg] bool: the foreground rows of a frame's own patch, not of a segment's copy."""
        return self.foreground.buffers[SEGMENT] >= self.num_segments

    def to_artifact(self, meta: Mapping[str, Any]) -> Artifact:
        """This model as an Artifact; `meta` adds stage-specific metadata (config, metrics)."""
        tensors = {**self.background.to_tensors("bg."), **self.foreground.to_tensors("fg.")}
        n_bg, n_fg = len(self.background), len(self.foreground)
        tensors["is_fg"] = torch.cat(
            [torch.zeros(n_bg, dtype=torch.bool), torch.ones(n_fg, dtype=torch.bool)]
        )
        tensors[SEGMENT] = torch.cat(
            [
                torch.full((n_bg,), -1, dtype=torch.int32),
                self.foreground.buffers[SEGMENT].to("cpu", torch.int32),
            ]
        )
        for prefix, module in ((FIELD_PREFIX, self.field), (AFFINE_PREFIX, self.affine)):
            if module is not None:
                tensors.update(
                    {prefix + k: v.detach().clone() for k, v in module.state_dict().items()}
                )
        body = {
            "num_frames": self.num_frames,
            "k": self.segments.uniform_length,
            **(
                {}
                if self.segments.uniform_length
                else {"segment_starts": list(self.segments.starts)}
            ),
            "num_segments": self.num_segments,
            "eps2d": self.eps2d,
            "antialiased": self.antialiased,
            "counts": {"bg": n_bg, "fg": n_fg, "total": n_bg + n_fg},
            "field": self.field_settings,
            "affine_cameras": list(self.affine_cameras),
        }
        tensors = {key: value.detach().to("cpu") for key, value in tensors.items()}
        return Artifact(stage=self.stage, tensors=tensors, meta={**body, **meta})

    @classmethod
    def from_artifact(cls, artifact: Artifact) -> SceneModel:
        """Rebuild the model a stage wrote (exact: the same tensors give the same renders)."""
        meta, tensors = artifact.meta, artifact.tensors
        if not isinstance(meta, Mapping):
            raise InputError(f"{artifact.stage} artifact: meta is a {type(meta).__name__}")
        segments = _segment_plan(artifact.stage, meta)
        background = GaussianSet.from_tensors(tensors, "bg.")
        foreground = GaussianSet.from_tensors(tensors, "fg.")
        if SEGMENT not in foreground.buffers:
            raise InputError(f"{artifact.stage} artifact: foreground has no 'segment' buffer")
        model = cls(
            stage=artifact.stage,
            background=background,
            foreground=foreground,
            segments=segments,
            eps2d=_recorded_eps2d(artifact.stage, meta),
            antialiased=_recorded_antialiased(artifact.stage, meta),
            field_settings=meta.get("field"),
            affine_cameras=list(meta.get("affine_cameras") or []),
        )
        if model.field_settings is not None:
            model.field = _restored(
                artifact, "field", lambda: build_field(model.field_settings), FIELD_PREFIX
            )
        if model.affine_cameras:
            model.affine = _restored(
                artifact, "affine", lambda: ColorAffine(len(model.affine_cameras)), AFFINE_PREFIX
            )
        return model

    def to(self, device: torch.device | str) -> SceneModel:
        """Move every tensor and module of this model to `device`, in place; returns the model."""
        self.background = self.background.to(device)
        self.foreground = self.foreground.to(device)
        if self.field is not None:
            self.field.to(device)
        if self.affine is not None:
            self.affine.to(device)
        return self


_Module = TypeVar("_Module", bound=torch.nn.Module)


def _restored(artifact: Artifact, what: str, build: Callable[[], _Module], prefix: str) -> _Module:
    """`build()` loaded with the artifact's `prefix` tensors; settings in its meta or tensors
    that do not fit are one line naming the artifact and `what` (the field or the affine)."""
    try:
        module = build()
        tensors = artifact.tensors.items()
        module.load_state_dict({k[len(prefix) :]: v for k, v in tensors if k.startswith(prefix)})
    except (AttributeError, KeyError, TypeError, ValueError, RuntimeError) as error:
        detail = textwrap.shorten(one_line(error), 300)
        raise InputError(
            f"{artifact.stage} artifact: its {what} does not match its settings ({detail})"
        ) from error
    return module


def build_field(settings: Mapping[str, Any], seed: int = 0) -> DeformationField:
    """A DeformationField from stored settings, initialised from `seed` (global RNG untouched)."""
    kwargs = {key: value for key, value in settings.items() if key != "aabb"}
    kwargs["multires"] = tuple(kwargs["multires"])
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return DeformationField(settings["aabb"], **kwargs)


def foreground_with_segments(foreground: GaussianSet, segments: Tensor) -> GaussianSet:
    """A copy of `foreground` whose `segment` buffer is `segments` (added if missing), on the
    set's device (a CPU buffer beside CUDA parameters would fail the first concat or index)."""
    tensors = {
        key: value for key, value in foreground.to_tensors().items() if key != f"buffer.{SEGMENT}"
    }
    tensors[f"buffer.{SEGMENT}"] = segments.to(foreground.means.device, torch.int32)
    return GaussianSet.from_tensors(tensors)


def replicate_foreground(foreground: GaussianSet, num_segments: int) -> GaussianSet:
    """S copies of `foreground` stacked, copy s tagged with segment s (extras and buffers too)."""
    tensors = foreground.to_tensors()
    stacked = {
        key: value.repeat(num_segments, *([1] * (value.ndim - 1))) if value.ndim else value
        for key, value in tensors.items()
    }
    count = len(foreground)
    segments = torch.arange(num_segments, dtype=torch.int32, device=foreground.means.device)
    stacked[f"buffer.{SEGMENT}"] = segments.repeat_interleave(count)
    return GaussianSet.from_tensors(stacked)


def core_only(gaussians: GaussianSet) -> GaussianSet:
    """The set without extra parameters and buffers (e.g. dropping decouple's mask logits)."""
    tensors = gaussians.to_tensors()
    kept = {
        key: value for key, value in tensors.items() if not key.startswith(("param.", "buffer."))
    }
    return GaussianSet.from_tensors(kept)


def _recorded_eps2d(stage: str, meta: Mapping[str, Any]) -> float:
    """The blur a model's meta records (one written before it was recorded: 0.3)."""
    value = meta.get("eps2d", EPS2D_BEFORE_RECORDED)
    valid = isinstance(value, int | float) and not isinstance(value, bool)
    if not (valid and 0.0 <= value < math.inf):
        raise InputError(f"{stage} artifact: meta 'eps2d' is {value!r}, not a number >= 0")
    return float(value)


def _recorded_antialiased(stage: str, meta: Mapping[str, Any]) -> bool:
    """Whether a model's meta records the antialiased blur (one written before: classic)."""
    value = meta.get("antialiased", False)
    if not isinstance(value, bool):
        raise InputError(f"{stage} artifact: meta 'antialiased' is {value!r}, not true or false")
    return value


def _segment_plan(stage: str, meta: Mapping[str, Any]) -> SegmentPlan:
    """The segments a model's meta records: its start frames, or (older) the length k."""
    for key in ("num_frames", *(() if "segment_starts" in meta else ("k",))):
        if not isinstance(meta.get(key), int) or meta[key] < 1:
            raise InputError(f"{stage} artifact: meta {key!r} missing or not an int >= 1")
    starts = meta.get("segment_starts")
    if starts is None:
        return SegmentPlan.uniform(meta["num_frames"], meta["k"])
    if not isinstance(starts, list) or not all(isinstance(s, int) for s in starts):
        raise InputError(f"{stage} artifact: meta 'segment_starts' is not a list of ints")
    try:
        return SegmentPlan(tuple(starts), meta["num_frames"])
    except InputError as error:
        raise InputError(f"{stage} artifact: meta {error}") from None
