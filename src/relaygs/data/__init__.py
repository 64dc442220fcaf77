"""Scenes: the Camera/View/Scene model, format loaders, metrics-ready images and synthetic data.

`load_scene(path)` reads the PanopticSports layout or multi-view video with COLMAP poses;
`relaygs.data.synthetic.generate` writes synthetic scenes in the Panoptic layout.
"""

from relaygs.data.camera import Camera
from relaygs.data.effects import ALL_EFFECTS
from relaygs.data.load import detect_format, load_scene
from relaygs.data.points import PointCloud
from relaygs.data.scene import Scene, View, frame_time

__all__ = [
    "ALL_EFFECTS",
    "Camera",
    "PointCloud",
    "Scene",
    "View",
    "detect_format",
    "frame_time",
    "load_scene",
]
