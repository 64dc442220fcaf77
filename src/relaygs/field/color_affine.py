"""Per-camera channel-wise colour affine image·e^a + b, for scenes with colour inconsistency."""

from __future__ import annotations

import torch
from torch import Tensor, nn

from relaygs.errors import InputError

# a is clamped to ±LOG_GAIN_LIMIT before exp: gains within [e^-5, e^5] ≈ [0.007, 148] cover
# any real exposure mismatch and keep e^a finite.
LOG_GAIN_LIMIT = 5.0


class ColorAffine(nn.Module):
    """Learnable per-camera gain (log_gain a) and offset (b), both [num_cameras, 3], init 0."""

    def __init__(self, num_cameras: int) -> None:
        super().__init__()
        if num_cameras < 1:
            raise InputError(f"ColorAffine num_cameras: expected >= 1, got {num_cameras}")
        self.log_gain = nn.Parameter(torch.zeros(num_cameras, 3))
        self.offset = nn.Parameter(torch.zeros(num_cameras, 3))

    def forward(self, image: Tensor, camera: int | Tensor) -> Tensor:
        """Corrected channel-last image(s): [H, W, 3] with an int camera, [B, H, W, 3] with [B]."""
        index = torch.as_tensor(camera, dtype=torch.long)  # an int stays on the host to check
        self._check(image, index)
        index = index.to(self.log_gain.device)
        lead = index.shape
        expand = (1,) * (image.dim() - 1 - len(lead))
        gain = torch.exp(self.log_gain[index].clamp(-LOG_GAIN_LIMIT, LOG_GAIN_LIMIT))
        return image * gain.view(*lead, *expand, 3) + self.offset[index].view(*lead, *expand, 3)

    def _check(self, image: Tensor, index: Tensor) -> None:
        if image.shape[-1:] != (3,) or image.dim() < 1 + index.dim() + 1:
            raise InputError(
                f"ColorAffine image: expected channel-last [..., 3], got {list(image.shape)}"
            )
        if index.dim() > 1 or (index.dim() == 1 and image.shape[0] != index.shape[0]):
            raise InputError(
                f"ColorAffine camera: expected an int or shape [{image.shape[0]}], "
                f"got {list(index.shape)}"
            )
        count = self.log_gain.shape[0]
        if index.numel() and bool(((index < 0) | (index >= count)).any()):
            raise InputError(
                f"ColorAffine camera: expected indices in [0, {count - 1}], got {index.tolist()}"
            )
