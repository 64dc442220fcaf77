"""Images side by side, each captioned above, so a TensorBoard picture says what it shows."""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np
import torch

MIN_PANEL_HEIGHT = 160  # lower panels are enlarged by a whole factor, so captions fit
CAPTION_HEIGHT = 22
FONT = cv2.FONT_HERSHEY_SIMPLEX
FONT_SCALE = 0.5
MARGIN = 4


def captioned_row(panels: Sequence[tuple[str, torch.Tensor]]) -> torch.Tensor:
    """[H',W',3] float32 in [0,1]: the same-sized images of `panels` side by side, enlarged to
    at least MIN_PANEL_HEIGHT rows, each under a black band with its caption in white."""
    height = panels[0][1].shape[0]
    factor = max(1, math.ceil(MIN_PANEL_HEIGHT / max(height, 1)))
    return torch.cat([_captioned(label, image, factor) for label, image in panels], dim=1)


def _captioned(label: str, image: torch.Tensor, factor: int) -> torch.Tensor:
    pixels = image.detach().float().cpu().clamp(0.0, 1.0)
    pixels = pixels.repeat_interleave(factor, dim=0).repeat_interleave(factor, dim=1)
    band = np.zeros((CAPTION_HEIGHT, pixels.shape[1], 3), dtype=np.uint8)
    (_, text_height), _ = cv2.getTextSize("T", FONT, FONT_SCALE, 1)  # a capital's height
    baseline = CAPTION_HEIGHT - (CAPTION_HEIGHT - text_height) // 2
    cv2.putText(band, label, (MARGIN, baseline), FONT, FONT_SCALE, (255, 255, 255), 1, cv2.LINE_AA)
    return torch.cat([torch.from_numpy(band).float() / 255.0, pixels], dim=0)
