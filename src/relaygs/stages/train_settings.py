"""The `train` section shared by every training stage: batch, loss weight, screen blur,
resolution, logging."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from relaygs.device import parse_device, usable_device
from relaygs.stages.config import Section, require


@dataclass
class TrainSettings(Section):
    """`cfg["train"]`, read by every stage; `eps2d` (px²) is added to every projected covariance
    when the models train and render, and `antialiased` scales each splat's opacity so that the
    blur keeps its screen integral (Mip-Splatting's 2D filter); downscale None is the paper's
    rule (`downscale_for`), an integer forces that factor on every stage. Periods are in
    steps."""

    section: ClassVar[str] = "train"
    batch_views: int = 4
    ssim_weight: float = 0.2
    eps2d: float = 0.1
    antialiased: bool = True
    downscale: int | None = None
    half_res_width: int = 320
    log_every: int = 100
    image_every: int = 0
    checkpoint_every: int = 500
    progress: bool = True
    device: str = "cpu"

    def validate(self) -> None:
        """Reject values no run could use (called once, when the run is planned)."""
        require(self.batch_views >= 1, "train.batch_views", self.batch_views, "an int >= 1")
        require(0.0 <= self.ssim_weight <= 1.0, "train.ssim_weight", self.ssim_weight, "[0, 1]")
        require(0.0 <= self.eps2d < math.inf, "train.eps2d", self.eps2d, "a finite number >= 0")
        factor = self.downscale
        require(factor is None or factor >= 1, "train.downscale", factor, "None or an int >= 1")
        require(self.half_res_width >= 1, "train.half_res_width", self.half_res_width, ">= 1")
        require(self.log_every >= 1, "train.log_every", self.log_every, "an int >= 1")
        require(self.image_every >= 0, "train.image_every", self.image_every, "an int >= 0")
        require(self.checkpoint_every >= 1, "train.checkpoint_every", self.checkpoint_every, ">= 1")
        parse_device(self.device, "train.device")  # usable here is checked where the job runs

    def blur(self) -> dict[str, Any]:
        """The screen blur as the keyword arguments of `splat`, FrozenRenders and SceneModel."""
        return {"eps2d": self.eps2d, "antialiased": self.antialiased}

    def torch_device(self) -> torch.device:
        """The training device, once this machine is known to allocate there."""
        return usable_device(self.device, "train.device")

    def downscale_for(self, image_width: int, early_stage: bool) -> int:
        """Resolution factor a stage trains at, given the scene's full image width: decouple and
        relay train at half resolution above `half_res_width` (the paper's rule), the rest full."""
        if self.downscale is not None:
            return self.downscale
        return 2 if early_stage and image_width > self.half_res_width else 1
