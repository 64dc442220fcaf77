"""The simulated camera: per-camera colour response (gain, offset) and sensor noise."""

from __future__ import annotations

import numpy as np

NOISE_SIGMA = 0.02
"""Standard deviation of the per-pixel Gaussian sensor noise, in [0, 1] intensity units."""
GAIN_RANGE = (0.85, 1.15)
OFFSET_RANGE = (-0.04, 0.04)


def camera_responses(num_cameras: int, seed: int, enabled: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera, per-channel (gains [C,3], offsets [C,3]); identity when `enabled` is False."""
    if not enabled:
        return np.ones((num_cameras, 3)), np.zeros((num_cameras, 3))
    rng = np.random.default_rng([seed, 21])
    gains = rng.uniform(*GAIN_RANGE, size=(num_cameras, 3))
    offsets = rng.uniform(*OFFSET_RANGE, size=(num_cameras, 3))
    return gains, offsets


def noise_generator(seed: int, camera: int, frame: int) -> np.random.Generator:
    """The noise stream of one image, independent of every other image's."""
    return np.random.default_rng([seed, 22, camera, frame])


def sensor_image(
    radiance: np.ndarray, gain: np.ndarray, offset: np.ndarray, noise: np.random.Generator | None
) -> np.ndarray:
    """Radiance [H,W,3] in [0,1] → 8-bit RGB: affine response, optional noise, clip, round."""
    image = radiance * gain + offset
    if noise is not None:
        image = image + noise.normal(0.0, NOISE_SIGMA, size=image.shape)
    return np.round(np.clip(image, 0.0, 1.0) * 255.0).astype(np.uint8)
