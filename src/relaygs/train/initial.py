"""Where training starts: 3DGS Gaussians from the scene's point cloud, and their session."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import torch

from relaygs.data import Scene
from relaygs.errors import InputError
from relaygs.model import MAX_LOG_SCALE, GaussianSet
from relaygs.train.session import SetPlan, TrainingSession


def initial_gaussians(
    scene: Scene, init_points: int | None, init_opacity: float, sh_degree: int, seed: int
) -> GaussianSet:
    """3DGS initialisation from the scene's point cloud, thinned to `init_points`."""
    xyz, rgb = scene.points.xyz, scene.points.rgb
    if init_points is not None and xyz.shape[0] > init_points:
        generator = torch.Generator().manual_seed(seed)
        keep = torch.randperm(xyz.shape[0], generator=generator)[:init_points].sort().values
        xyz, rgb = xyz[keep], rgb[keep]
    gaussians = GaussianSet.from_points(xyz, rgb, sh_degree, init_opacity)
    # mostly larger than the renderer's size cap (a scene in huge units), their sizes would get
    # no gradient and the scene would train to nothing
    log_scales = gaussians.params["log_scales"].detach()[:, 0]
    over = int((log_scales > MAX_LOG_SCALE).sum())
    if 2 * over > len(log_scales):
        raise InputError(
            f"{scene.root}: {over} of the {len(log_scales)} initial points lie more than "
            f"{math.exp(MAX_LOG_SCALE):.2g} units from their neighbours, the largest Gaussian "
            "the renderer draws; expected a scene in units near metres (rescale the poses' "
            "translations and the point cloud alike)"
        )
    return gaussians


def static_session(
    name: str,
    scene: Scene,
    section: Any,
    plan: SetPlan,
    seed: int,
    device: torch.device,
    extras: Mapping[str, float] | None = None,
) -> TrainingSession:
    """The session of a stage fitting one set from the point cloud, plus trainable `extras`."""
    gaussians = initial_gaussians(
        scene, section.init_points, section.init_opacity, section.sh_degree, seed
    )
    for param, value in (extras or {}).items():
        gaussians.add_param(param, torch.full((len(gaussians),), value))
    return TrainingSession(
        sets={name: gaussians.to(device)},
        plans={name: plan},
        extent=scene.extent,
        seed=seed,
        device=device,
    )
