"""Reading image files: size and integrity from the bytes, decoding to float RGB and masks."""

from __future__ import annotations

import zlib
from pathlib import Path

import cv2
import numpy as np

from relaygs.errors import InputError

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SOI = b"\xff\xd8"
_JPEG_EOI = 0xD9
_JPEG_SOS = 0xDA
_JPEG_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
_JPEG_STANDALONE_MARKERS = frozenset({0x01, *range(0xD0, 0xD9)})  # TEM, RST0-7, SOI


def image_size(data: bytes, path: Path) -> tuple[int, int]:
    """(width, height) of an image file's bytes: PNG and JPEG from a checked header (damaged files
    refused before training), other types by decoding."""
    if data.startswith(_PNG_SIGNATURE):
        if len(data) < 24 or data[12:16] != b"IHDR":
            raise InputError(f"{path}: not a readable image (truncated PNG header)")
        _check_png_chunks(data, path)
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if data.startswith(_JPEG_SOI):
        return _jpeg_size(data, path)
    if not data:
        raise InputError(f"{path}: empty file, expected an image")
    decoded = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if decoded is None:
        raise InputError(f"{path}: not a readable image")
    return int(decoded.shape[1]), int(decoded.shape[0])


def _check_png_chunks(data: bytes, path: Path) -> None:
    """Walk the chunks after the signature: each must fit the file and pass its CRC32, at least
    one IDAT must come before IEND, and IEND must be reached (bytes after it are ignored)."""
    view = memoryview(data)
    pos, seen_idat = len(_PNG_SIGNATURE), False
    while pos + 12 <= len(data):
        length = int.from_bytes(data[pos : pos + 4], "big")
        kind = data[pos + 4 : pos + 8].decode("ascii", "backslashreplace")
        end = pos + 8 + length
        if end + 4 > len(data):
            raise _damaged(path, f"chunk {kind} is cut short: truncated")
        if zlib.crc32(view[pos + 4 : end]) != int.from_bytes(data[end : end + 4], "big"):
            raise _damaged(path, f"chunk {kind} fails its CRC")
        if kind == "IEND":
            if not seen_idat:
                raise _damaged(path, "no IDAT image data")
            return
        seen_idat = seen_idat or kind == "IDAT"
        pos = end + 4
    raise _damaged(path, "no IEND chunk: truncated")


def _damaged(path: Path, reason: str) -> InputError:
    return InputError(f"{path}: damaged image file ({reason})")


def _jpeg_size(data: bytes, path: Path) -> tuple[int, int]:
    """(width, height) from a JPEG's frame header, walking segments and scans to EOI: a file
    stopping before it is truncated, bytes after it (a motion photo's video) are ignored."""
    pos, size = 2, None
    while (pos := data.find(b"\xff", pos)) >= 0 and pos + 1 < len(data):
        marker = data[pos + 1]  # bytes between segments are skipped, as libjpeg does
        if marker == _JPEG_EOI:
            if size is None:
                raise InputError(f"{path}: not a readable image (no JPEG frame header found)")
            return size
        if marker == 0xFF or marker in _JPEG_STANDALONE_MARKERS:
            pos += 1 if marker == 0xFF else 2  # a fill byte, or a marker without a length
            continue
        if marker in _JPEG_SOF_MARKERS and pos + 9 <= len(data):
            height = int.from_bytes(data[pos + 5 : pos + 7], "big")
            width = int.from_bytes(data[pos + 7 : pos + 9], "big")
            size = (width, height)
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker == _JPEG_SOS:
            pos = _end_of_scan(data, pos)
    raise _damaged(path, "no JPEG end marker FFD9: truncated")


def _end_of_scan(data: bytes, pos: int) -> int:
    """End of the scan data from `pos`: the first 0xFF that is no stuffed 0xFF00 nor RST0-7."""
    while (pos := data.find(b"\xff", pos)) >= 0 and pos + 1 < len(data):
        if data[pos + 1] != 0x00 and not 0xD0 <= data[pos + 1] <= 0xD7:
            return pos
        pos += 2
    return len(data)


def read_rgb(path: Path, width: int, height: int) -> np.ndarray:
    """An 8- or 16-bit image as float32 RGB [height,width,3] in [0,1], area-resized; no EXIF
    rotation, as in COLMAP, so pixels match the header size and the intrinsics."""
    flags = cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH | cv2.IMREAD_IGNORE_ORIENTATION
    bgr = cv2.imread(str(path), flags)
    if bgr is None:
        raise InputError(f"{path}: cannot decode image")
    rgb = cv2.cvtColor(_unit_range(bgr, path), cv2.COLOR_BGR2RGB)
    return _resize(rgb, width, height)


def _unit_range(pixels: np.ndarray, path: Path) -> np.ndarray:
    """Integer pixels / their type's maximum, as float32 (a 16-bit image keeps its low bits)."""
    if pixels.dtype not in (np.uint8, np.uint16):
        raise InputError(f"{path}: {pixels.dtype} pixels, expected an 8- or 16-bit image")
    return pixels.astype(np.float32) / np.float32(np.iinfo(pixels.dtype).max)


def read_mask(path: Path, width: int, height: int) -> np.ndarray:
    """A mask image as bool [height,width]: non-zero in any colour channel, as stored."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise InputError(f"{path}: cannot decode mask image")
    coverage = _resize(_nonzero(raw).astype(np.float32), width, height)
    return coverage >= 0.5


def _nonzero(raw: np.ndarray) -> np.ndarray:
    """Where a mask [H,W] or [H,W,C] is non-zero in any colour channel (alpha left out): 8-bit
    grey would lose 16-bit labels below 256 and faint colours."""
    if raw.ndim == 2:
        return raw != 0
    return (raw[..., :3] != 0).any(axis=2)


def _resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    if image.shape[1] == width and image.shape[0] == height:
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
