"""Scenes: the Camera/View/Scene model, `load_scene` for the Panoptic and multi-view layouts,
and synthetic scenes (`relaygs.data.synthetic.generate`)."""

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
