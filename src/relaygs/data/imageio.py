"""Reading image files: size from the header bytes, decoding to float RGB and boolean masks."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from relaygs.errors import InputError

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_STANDALONE_MARKERS = frozenset({0x01, *range(0xD0, 0xDA)})


def image_size(data: bytes, path: Path) -> tuple[int, int]:
    """(width, height) of a PNG or JPEG from its header; other types are decoded to find out."""
    if data.startswith(_PNG_SIGNATURE):
        if len(data) < 24 or data[12:16] != b"IHDR":
            raise InputError(f"{path}: not a readable image (truncated PNG header)")
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if data.startswith(b"\xff\xd8"):
        return _jpeg_size(data, path)
    decoded = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if decoded is None:
        raise InputError(f"{path}: not a readable image")
    return int(decoded.shape[1]), int(decoded.shape[0])


def _jpeg_size(data: bytes, path: Path) -> tuple[int, int]:
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            break
        marker = data[pos + 1]
        if marker == 0xFF:
            pos += 1
            continue
        if marker in _JPEG_STANDALONE_MARKERS:
            pos += 2
            continue
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker in _JPEG_SOF_MARKERS and pos + 9 <= len(data):
            height = int.from_bytes(data[pos + 5 : pos + 7], "big")
            width = int.from_bytes(data[pos + 7 : pos + 9], "big")
            return width, height
        pos += 2 + length
    raise InputError(f"{path}: not a readable image (no JPEG frame header found)")


def read_rgb(path: Path, width: int, height: int) -> np.ndarray:
    """Decode an image to float32 RGB [height,width,3] in [0,1], area-resized when sizes differ."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputError(f"{path}: cannot decode image")
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).astype(np.float32) / np.float32(255.0)
    return _resize(rgb, width, height)


def read_mask(path: Path, width: int, height: int) -> np.ndarray:
    """Decode a mask image (any non-zero value is foreground) to bool [height,width]."""
    raw = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if raw is None:
        raise InputError(f"{path}: cannot decode mask image")
    coverage = _resize((raw > 0).astype(np.float32), width, height)
    return coverage >= 0.5


def _resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    if image.shape[1] == width and image.shape[0] == height:
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
