"""A stored model as 3DGS-layout PLY files, one per frame, with the values before activation
that 3DGS stores (no per-camera colour affine), so splat viewers open what a run made."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from relaygs.data.scene import frame_time
from relaygs.errors import InputError, RelayGSError
from relaygs.model import MAX_LOG_SCALE, normalize_quats
from relaygs.pipeline.fsio import publish_bytes
from relaygs.progress import progress_bar
from relaygs.splat.sh import num_sh_bases
from relaygs.train.model_render import ModelRenderer
from relaygs.train.render import Part
from relaygs.train.scene_model import SceneModel

PLY_DTYPE = "<f4"  # every property is a little-endian float32, as 3DGS writes them


def ply_columns(parts: Sequence[Part], sh_degree: int) -> dict[str, torch.Tensor]:
    """The 3DGS PLY properties in file order: name → [N] float32; SH zero-filled to `sh_degree`
    (3DGS reads its model's full degree)."""
    means = torch.cat([part.means for part in parts])
    sh = torch.cat([part.sh for part in parts])  # [N, K, 3]
    missing = num_sh_bases(sh_degree) - sh.shape[1]
    if missing > 0:
        sh = torch.cat([sh, sh.new_zeros(sh.shape[0], missing, 3)], dim=1)
    columns = {name: means[:, axis] for axis, name in enumerate("xyz")}
    columns.update({name: torch.zeros_like(means[:, 0]) for name in ("nx", "ny", "nz")})
    columns.update({f"f_dc_{channel}": sh[:, 0, channel] for channel in range(3)})
    rest = sh[:, 1:, :].transpose(1, 2).flatten(1)  # channel-major, as 3DGS
    columns.update({f"f_rest_{index}": rest[:, index] for index in range(rest.shape[1])})
    columns["opacity"] = torch.cat([part.opacity_logits for part in parts])
    log_scales = torch.cat([part.log_scales for part in parts]).clamp(max=MAX_LOG_SCALE)
    columns.update({f"scale_{axis}": log_scales[:, axis] for axis in range(3)})
    quats = normalize_quats(torch.cat([part.quats for part in parts]))
    columns.update({f"rot_{index}": quats[:, index] for index in range(4)})
    return columns


def ply_bytes(columns: dict[str, torch.Tensor]) -> bytes:
    """A binary little-endian PLY with one `vertex` element holding `columns`."""
    count = next(iter(columns.values())).shape[0]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    header += [f"property float {name}" for name in columns]
    header.append("end_header\n")
    rows = np.empty(count, dtype=[(name, PLY_DTYPE) for name in columns])
    for name, values in columns.items():
        rows[name] = values.detach().to("cpu", torch.float32).numpy()
    return "\n".join(header).encode("ascii") + rows.tobytes()


def write_frame_plys(
    model: SceneModel, out: Path, frames: Sequence[int], progress: bool = True
) -> list[Path]:
    """Write `out`/<frame>.ply for `frames` and return their paths: all or, on a failure or an
    interrupt, none; a frame not in the model or a non-finite value is one line naming it."""
    outside = [frame for frame in frames if not 0 <= frame < model.num_frames]
    if outside:
        raise InputError(
            f"frame {outside[0]} is not in the model: its frames are 0..{model.num_frames - 1}"
        )
    renderer = ModelRenderer(model)
    sh_degree = max(model.background.max_sh_degree, model.foreground.max_sh_degree)
    written: list[Path] = []
    try:
        bar = progress_bar(frames, desc="ply", unit="frame", disable=not progress, leave=False)
        for frame in bar:
            parts = renderer.parts_at(frame_time(frame, model.num_frames))
            written.append(_write_frame(out, frame, ply_columns(parts, sh_degree)))
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        raise
    return written


def _write_frame(out: Path, frame: int, columns: dict[str, torch.Tensor]) -> Path:
    """Publish `out`/<frame>.ply after checking every value is finite; returns its path."""
    for name, values in columns.items():
        if not torch.isfinite(values).all():
            raise RelayGSError(f"frame {frame}: property {name} is not finite; nothing written")
    path = out / f"{frame:06d}.ply"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        publish_bytes(path, ply_bytes(columns))
    except OSError as error:  # e.g. a file where the folder goes
        where = error.filename or path
        raise InputError(f"cannot write {where}: {error.strerror or error}") from error
    return path
