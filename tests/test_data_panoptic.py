"""Loading the PanopticSports layout: views, cameras, lazy images, downscale, fingerprint."""

from __future__ import annotations

import json
import pickle
import struct
import zlib
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from refusals import refused
from relaygs.data import Camera, Scene, View, load_scene
from relaygs.data.effects import COLOR_INCONSISTENCY, SENSOR_NOISE
from relaygs.errors import InputError
from relaygs.model import GaussianSet
from relaygs.train.render import part_of, splat

EPS2D = 0.3  # screen blur of these renders (px², the rasterizer's default)


@pytest.fixture(scope="module")
def scene(tiny_synth_scene: Path) -> Scene:
    return load_scene(tiny_synth_scene)


def test_views_cameras_extent_images_and_points(scene: Scene, tiny_synth_scene: Path):
    assert scene.format == "panoptic" and scene.name == "juggle"
    assert scene.num_frames == 6
    assert len(scene.train_views) == 27 * 6 and len(scene.test_views) == 4 * 6
    assert [camera.camera_id for camera in scene.test_cameras] == [0, 10, 15, 30]
    assert len(scene.train_cameras) == 27
    for view in scene.train_views + scene.test_views:
        assert view.time == pytest.approx(view.frame / 5)
        assert view.image_path.is_file() and view.mask_path.is_file()
    frame_views = scene.views_at(3, "all")
    assert len(frame_views) == 31 and {view.frame for view in frame_views} == {3}
    assert scene.views_at(0, "train")[0].camera is scene.views_at(5, "train")[0].camera
    meta = json.loads((tiny_synth_scene / "test_meta.json").read_text())
    camera = scene.views_at(2, "test")[1]
    assert camera.camera.camera_id == meta["cam_id"][2][1]
    assert torch.allclose(camera.camera.K, torch.tensor(meta["k"][2][1], dtype=torch.float32))
    assert torch.allclose(camera.camera.w2c, torch.tensor(meta["w2c"][2][1], dtype=torch.float32))
    assert camera.camera.K.dtype == torch.float32 and camera.camera.w2c.shape == (4, 4)
    centers = torch.stack([camera.center for camera in scene.train_cameras]).double()
    radius = (centers - centers.mean(0)).norm(dim=1).max().item()
    assert scene.extent == pytest.approx(1.1 * radius, rel=1e-6)
    view = scene.train_views[40]
    image = scene.image(view)
    assert image.shape == (18, 32, 3) and image.dtype == torch.float32
    assert image.min().item() >= 0.0 and image.max().item() <= 1.0
    raw = cv2.imread(str(view.image_path))[..., ::-1]
    assert torch.equal(image, torch.from_numpy(raw.astype(np.float32) / 255.0))
    mask = scene.mask(view)
    assert mask.shape == (18, 32) and mask.dtype == torch.bool
    assert scene.image(view) is image
    data = np.load(tiny_synth_scene / "init_pt_cld.npz")["data"]
    assert len(scene.points) == len(data)
    assert torch.allclose(scene.points.xyz, torch.from_numpy(data[:, :3]))
    assert torch.equal(scene.points.is_fg, torch.from_numpy(data[:, 6] > 0.5))
    declared = json.loads((tiny_synth_scene / "scene.json").read_text())["effects"]
    assert scene.effects == frozenset(declared)
    overridden = load_scene(tiny_synth_scene, effects=[SENSOR_NOISE])
    assert overridden.effects == {SENSOR_NOISE}
    assert COLOR_INCONSISTENCY in scene.effects


def test_a_single_train_camera_takes_its_extent_from_the_points(tiny_synth_copy: Path):
    path = tiny_synth_copy / "train_meta.json"
    meta = json.loads(path.read_text())
    for field in ("k", "w2c", "fn", "cam_id"):
        meta[field] = [row[:1] for row in meta[field]]
    path.write_text(json.dumps(meta))
    scene = load_scene(tiny_synth_copy)
    assert len(scene.train_cameras) == 1
    xyz = scene.points.xyz.double()
    radius = (xyz - xyz.mean(0)).norm(dim=1).max().item()
    assert radius > 0.1
    assert scene.extent == pytest.approx(1.1 * radius, rel=1e-6)


def _view_of(scene: Scene, image_path: Path) -> View:
    return next(view for view in scene.train_views if view.image_path == image_path)


def _with_orientation(data: bytes, orientation: int) -> bytes:
    """An image file's bytes with an EXIF Orientation tag (a little-endian TIFF block holding one
    SHORT): an APP1 segment after a JPEG's SOI, an eXIf chunk after a PNG's IHDR."""
    entry = struct.pack("<HHHIHH", 1, 0x0112, 3, 1, orientation, 0)
    exif = b"II*\x00" + struct.pack("<I", 8) + entry + struct.pack("<I", 0)
    if data.startswith(b"\xff\xd8"):
        payload = b"Exif\x00\x00" + exif
        return data[:2] + b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload + data[2:]
    chunk = b"eXIf" + exif
    crc = struct.pack(">I", zlib.crc32(chunk))
    return data[:33] + struct.pack(">I", len(exif)) + chunk + crc + data[33:]


@pytest.mark.parametrize("name", ["ims/1/000000.jpg", "ims/1/000000.png", "seg/1/000000.png"])
def test_exif_orientation_is_not_applied(tiny_synth_copy: Path, name: str):
    """w/h and the intrinsics (like COLMAP's) describe pixels as stored: a rotate-90° tag must not
    turn a 32×18 frame into 18×32 pixels squeezed back to 32×18."""
    path = tiny_synth_copy / name
    if path.suffix == ".jpg":
        png = path.with_suffix(".png")
        path.write_bytes(cv2.imencode(".jpg", cv2.imread(str(png)))[1].tobytes())
        png.unlink()
        meta_path = tiny_synth_copy / "train_meta.json"
        meta_path.write_text(meta_path.read_text().replace('"1/000000.png"', '"1/000000.jpg"'))
    plain = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    path.write_bytes(_with_orientation(path.read_bytes(), 6))
    scene = load_scene(tiny_synth_copy)
    view = _view_of(scene, tiny_synth_copy / "ims" / "1" / f"000000{path.suffix}")
    if name.startswith("seg"):
        assert torch.equal(scene.mask(view), torch.from_numpy(plain > 0))
    else:
        assert torch.equal(scene.image(view), torch.from_numpy(plain[..., ::-1] / np.float32(255)))


def test_16_bit_images_keep_their_low_bits(tiny_synth_copy: Path):
    path = tiny_synth_copy / "ims" / "1" / "000000.png"
    pixels = np.random.default_rng(0).integers(0, 65536, (18, 32, 3), dtype=np.uint16)
    pixels[0, :3] = [1, 200, 65535]
    cv2.imwrite(str(path), pixels)
    scene = load_scene(tiny_synth_copy)
    image = scene.image(_view_of(scene, path))
    expected = pixels[..., ::-1].astype(np.float32) / np.float32(65535)
    assert torch.allclose(image, torch.from_numpy(expected), rtol=0, atol=1e-7)


@pytest.mark.parametrize(
    "encode",
    [
        lambda fg: fg.astype(np.uint16),
        lambda fg: np.stack([fg, 0 * fg, 0 * fg], axis=-1).astype(np.uint8),
        lambda fg: np.stack([fg * 255, fg * 255, fg * 255, 0 * fg + 255], axis=-1).astype(np.uint8),
    ],
    ids=["16-bit label", "faint colour", "white on opaque alpha"],
)
def test_mask_foreground_is_any_non_zero_grey_or_colour_value(
    tiny_synth_copy: Path, encode: Callable[[np.ndarray], np.ndarray]
):
    """16-bit label 1 and colour (0, 0, 1) are foreground (an 8-bit grey conversion would make
    both 0); an opaque alpha channel is not."""
    path = tiny_synth_copy / "seg" / "1" / "000000.png"
    fg = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) > 0
    assert fg.any() and not fg.all()
    cv2.imwrite(str(path), encode(fg))
    scene = load_scene(tiny_synth_copy)
    view = _view_of(scene, tiny_synth_copy / "ims" / "1" / "000000.png")
    assert torch.equal(scene.mask(view), torch.from_numpy(fg))


def test_downscale_halves_cameras_and_area_resizes_images(scene: Scene, tiny_synth_scene: Path):
    half = load_scene(tiny_synth_scene, downscale=2)
    full_view, half_view = scene.train_views[7], half.train_views[7]
    assert (half_view.camera.width, half_view.camera.height) == (16, 9)
    assert torch.allclose(half_view.camera.K[:2], full_view.camera.K[:2] / 2)
    assert torch.equal(half_view.camera.w2c, full_view.camera.w2c)
    expected = cv2.resize(scene.image(full_view).numpy(), (16, 9), interpolation=cv2.INTER_AREA)
    assert torch.allclose(half.image(half_view), torch.from_numpy(expected))
    assert half.mask(half_view).shape == (9, 16)
    rescaled = scene.rescaled(2)
    assert torch.equal(rescaled.train_views[7].camera.K, half_view.camera.K)
    assert rescaled.fingerprint == half.fingerprint != scene.fingerprint
    assert load_scene(tiny_synth_scene, downscale=5).train_views[0].camera.height == 4
    with refused(InputError, str(tiny_synth_scene), "downscale 9", "32x18", "4x2"):
        load_scene(tiny_synth_scene, downscale=9)


def test_camera_scaling_keeps_pixel_edges_consistent():
    K = torch.tensor([[20.0, 0, 16.0], [0, 20.0, 9.0], [0, 0, 1]])
    base = Camera(3, K, torch.eye(4), 32, 18)
    point = torch.tensor([0.3, -0.2, 2.0])
    for factor in (2, 4, 3):
        scaled = base.scaled(factor)
        uv_full = (base.K @ point)[:2] / point[2]
        uv_scaled = (scaled.K @ point)[:2] / point[2]
        ratio = torch.tensor([scaled.width / 32, scaled.height / 18])
        assert torch.allclose(uv_scaled, uv_full * ratio, atol=1e-5)
    assert base.scaled(1) is base


def test_cache_stays_within_its_budget(tiny_synth_scene: Path):
    one_image_mb = 18 * 32 * 3 * 4 / 2**20
    small = load_scene(tiny_synth_scene, cache_mb=2.5 * one_image_mb)
    for view in small.train_views[:10]:
        small.image(view)
    assert len(small.cache) == 2
    assert small.cache.used_bytes <= small.cache.budget_bytes
    clone = pickle.loads(pickle.dumps(small))
    assert len(clone.cache) == 0 and clone.cache.budget_bytes == small.cache.budget_bytes
    assert torch.equal(clone.image(clone.train_views[3]), small.image(small.train_views[3]))


def test_fingerprint_is_stable_and_tracks_content_and_options(tiny_synth_copy: Path):
    base = load_scene(tiny_synth_copy).fingerprint
    assert load_scene(tiny_synth_copy, cache_mb=64).fingerprint == base
    variants = {
        load_scene(tiny_synth_copy, downscale=2).fingerprint,
        load_scene(tiny_synth_copy, max_points=500).fingerprint,
        load_scene(tiny_synth_copy, test_cameras=[1, 2]).fingerprint,
        load_scene(tiny_synth_copy, effects=[]).fingerprint,
    }
    assert base not in variants and len(variants) == 4
    image_path = tiny_synth_copy / "ims" / "3" / "000002.png"
    image = cv2.imread(str(image_path))
    image[5, 7] = 255 - image[5, 7]
    cv2.imwrite(str(image_path), image)
    edited = load_scene(tiny_synth_copy).fingerprint
    assert edited != base
    meta_path = tiny_synth_copy / "train_meta.json"  # a same-size edit of a meta file
    text = meta_path.read_text()
    meta_path.write_text(text.replace('"w": 32', '"w":32 ', 1))
    assert len(meta_path.read_text()) == len(text)
    assert load_scene(tiny_synth_copy).fingerprint not in {base, edited}


def test_the_test_cameras_option_regroups_views_with_or_without_test_meta(
    tiny_synth_copy: Path,
):
    regrouped = load_scene(tiny_synth_copy, test_cameras=[1, 10, 2])
    assert [camera.camera_id for camera in regrouped.test_cameras] == [1, 2, 10]
    assert len(regrouped.train_cameras) == 28
    (tiny_synth_copy / "test_meta.json").unlink()
    scene = load_scene(tiny_synth_copy, test_cameras=[1, 2])
    assert [camera.camera_id for camera in scene.test_cameras] == [1, 2]
    assert len(scene.train_cameras) == 25  # juggle's 27 train cameras less the two held out
    assert len(scene.test_views) == 2 * scene.num_frames
    assert load_scene(tiny_synth_copy, test_cameras=[]).test_views == []
    with refused(InputError, "[0]"):
        load_scene(tiny_synth_copy, test_cameras=[0])  # a camera of the removed test_meta.json


def test_a_scene_in_small_units_renders_like_the_same_scene_in_metres(
    scene: Scene, tiny_synth_copy: Path
):
    """The near plane scales with the extent below 1: at 1/1000 scale the cameras are ~4 mm
    from the subject, and gsplat's fixed 0.01 would cull almost every Gaussian."""
    factor = 1e-3
    for name in ("train_meta.json", "test_meta.json"):  # camera translations and the cloud
        meta = json.loads((tiny_synth_copy / name).read_text())
        w2c = np.array(meta["w2c"])
        w2c[..., :3, 3] *= factor
        meta["w2c"] = w2c.tolist()
        (tiny_synth_copy / name).write_text(json.dumps(meta))
    data = np.load(tiny_synth_copy / "init_pt_cld.npz")["data"] * ([factor] * 3 + [1] * 4)
    np.savez(tiny_synth_copy / "init_pt_cld.npz", data=data)
    small = load_scene(tiny_synth_copy)
    assert small.extent == pytest.approx(scene.extent * factor, rel=1e-4)
    assert {view.camera.near for view in scene.train_views + scene.test_views} == {0.01}
    nears = {view.camera.near for view in small.train_views + small.test_views}
    assert nears == {0.01 * small.extent}
    assert small.rescaled(2).train_cameras[0].near == small.train_cameras[0].near

    big = GaussianSet.from_points(scene.points.xyz, scene.points.rgb, max_sh_degree=0)
    tiny = GaussianSet.from_points(scene.points.xyz, scene.points.rgb, max_sh_degree=0)
    tiny.params["means"].data.mul_(factor)
    tiny.params["log_scales"].data.add_(float(np.log(factor)))
    cameras = small.test_cameras
    assert cameras[0].near < 0.01 and scene.test_cameras[0].near == 0.01
    expected = splat([part_of("all", big, 0, frozen=True)], scene.test_cameras, 0, eps2d=EPS2D)
    got = splat([part_of("all", tiny, 0, frozen=True)], cameras, 0, eps2d=EPS2D)
    for want, have in zip(expected.alphas, got.alphas, strict=True):
        assert float(want.mean()) > 0.2
        assert torch.allclose(have, want, atol=1e-3)
