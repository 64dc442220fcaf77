"""Before the photometric steps, fit the field's foreground motion to each frame's visual hull
alone (no renders): a copy that spans many frames then starts at its movers in every frame,
where the photometric loss can refine it, instead of having to find them from images it no
longer overlaps."""

from __future__ import annotations

import torch

from relaygs.data import frame_time
from relaygs.field import DeformationField
from relaygs.stages.frame_hulls import FrameHulls
from relaygs.train.motion import foreground_means
from relaygs.train.scene_model import GAMMA, SceneModel

FRAMES_PER_STEP = 4  # frames whose hulls one prefit step fits


def prefit_foreground_motion(
    model: SceneModel,
    hulls: FrameHulls,
    steps: int,
    rates: dict[str, float],
    regularisers: dict[str, float],
    coverage: float,
    extent: float,
    seed: int,
) -> None:
    """`steps` Adam steps on the HexPlane and the foreground MLP set (rates "grid", "mlp")
    minimising the hull distance (with `coverage`) of the shown copy at random frames, in units
    of the scene's `extent`, plus the field's weighted `regularisers`."""
    field: DeformationField = model.field
    frames = sorted(hulls.points)
    if steps == 0 or not frames or len(model.foreground) == 0:
        return
    optimiser = torch.optim.Adam(
        [
            {"params": field.parameter_groups()["grid"], "lr": rates["grid"] * extent},
            {"params": field.foreground_set().parameters(), "lr": rates["mlp"] * extent},
        ],
        eps=1e-15,
    )
    generator = torch.Generator().manual_seed(seed)
    num_frames = model.num_frames
    for _ in range(steps):
        picks = torch.randint(len(frames), (FRAMES_PER_STEP,), generator=generator).tolist()
        terms = []
        for frame in (frames[pick] for pick in picks):
            rows = model.foreground_rows(frame)
            xyz = model.foreground.means[rows].detach()
            gamma = model.foreground.params.get(GAMMA)
            gamma = None if gamma is None else gamma[rows].detach()
            means = foreground_means(xyz, gamma, field, frame_time(frame, num_frames))
            terms.append(hulls.distance(means, frame, coverage))
        loss = torch.stack(terms).mean() / extent
        values = field.regularisers()
        for name, weight in regularisers.items():
            loss = loss + weight * values[name]
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
