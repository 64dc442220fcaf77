"""Writing the reports' matplotlib figures."""

from __future__ import annotations

import io
from pathlib import Path

from matplotlib.figure import Figure

from relaygs.pipeline.fsio import publish_bytes

DPI = 120


def save_png(figure: Figure, path: Path) -> Path:
    """Write `figure` to `path` as PNG, whole: a concurrent report never leaves half a plot."""
    image = io.BytesIO()
    figure.savefig(image, format="png", dpi=DPI)
    path = Path(path)
    publish_bytes(path, image.getvalue())
    return path
