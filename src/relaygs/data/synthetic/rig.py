"""Camera rigs of the synthetic presets: a Panoptic-like dome and a 360° ring around a court."""

from __future__ import annotations

import numpy as np

from relaygs.data.synthetic.world import RigCamera

DOME_FOCAL = 1.0  # dome focal length per image-height pixel (vertical field of view ≈ 53°)
RING_FOCAL = 0.9  # ring focal length per image-height pixel (vertical field of view ≈ 58°)


def intrinsics(width: int, height: int, focal_per_height: float) -> np.ndarray:
    """Square-pixel pinhole intrinsics with the principal point at the image centre."""
    focal = focal_per_height * height
    return np.array([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]])


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """World→camera [4,4] (OpenCV: x right, y down, z forward) for a camera at `eye` with z up."""
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    w2c = np.eye(4)
    w2c[:3, :3] = np.stack([right, down, forward])
    w2c[:3, 3] = -w2c[:3, :3] @ eye
    return w2c


def dome_rig(width: int, height: int) -> list[RigCamera]:
    """31 cameras on three rings of a hemisphere (radius 4.5 m) looking at the stage centre."""
    K = intrinsics(width, height, DOME_FOCAL)
    target = np.array([0.0, 0.0, 1.0])
    cameras = []
    for ring, (count, elevation_deg) in enumerate(((13, 6.0), (11, 27.0), (7, 50.0))):
        elevation = np.radians(elevation_deg)
        for index in range(count):
            azimuth = 2 * np.pi * (index + 0.5 * ring) / count
            direction = np.array(
                [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), 0.0]
            )
            direction[2] = np.sin(elevation)
            eye = target + 4.5 * direction
            cameras.append(RigCamera(K, look_at(eye, target)))
    return cameras


def ring_rig(width: int, height: int) -> list[RigCamera]:
    """34 cameras on an elliptical 360° ring (11 m × 7.8 m) around the court, looking inwards."""
    K = intrinsics(width, height, RING_FOCAL)
    target = np.array([0.0, 0.0, 1.0])
    cameras = []
    for index in range(34):
        angle = 2 * np.pi * index / 34
        eye = np.array([11.0 * np.cos(angle), 7.8 * np.sin(angle), 2.6 + 0.6 * (index % 2)])
        cameras.append(RigCamera(K, look_at(eye, target)))
    return cameras
