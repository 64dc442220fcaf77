"""Multi-view layout with COLMAP poses: binary and text models agree with the Panoptic loader."""

from __future__ import annotations

import json
import shutil
import struct
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from refusals import refused
from relaygs.data import Scene, load_scene
from relaygs.data.colmap import (
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    model_suffix,
    qvec_to_rotation,
    read_model,
    rotation_to_qvec,
    write_model,
)
from relaygs.data.export import export_multiview
from relaygs.data.fingerprint import digest, file_record
from relaygs.data.options import make_options
from relaygs.errors import InputError

JUGGLE_TEST_CAMERAS = [0, 10, 15, 30]


@pytest.fixture(scope="module")
def panoptic(tiny_synth_scene: Path) -> Scene:
    return load_scene(tiny_synth_scene)


@pytest.fixture(scope="module", params=["binary", "text"])
def multiview_root(request, panoptic: Scene, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("multiview") / request.param
    return export_multiview(panoptic, out, binary=request.param == "binary")


def test_both_loaders_agree_on_cameras_images_and_points(panoptic: Scene, multiview_root: Path):
    multiview = load_scene(multiview_root)  # the export's scene.json keeps juggle's test cameras
    assert multiview.format == "multiview" and multiview.num_frames == panoptic.num_frames
    for split in ("train_views", "test_views"):
        expected, actual = getattr(panoptic, split), getattr(multiview, split)
        assert len(expected) == len(actual)
        for ours, theirs in zip(expected, actual, strict=True):
            assert (ours.frame, ours.camera.camera_id) == (theirs.frame, theirs.camera.camera_id)
            assert ours.time == theirs.time
            assert torch.allclose(ours.camera.K, theirs.camera.K, atol=1e-5)
            assert torch.allclose(ours.camera.w2c, theirs.camera.w2c, atol=1e-5)
    for index in (0, 17, 100):
        ours, theirs = panoptic.train_views[index], multiview.train_views[index]
        assert torch.equal(panoptic.image(ours), multiview.image(theirs))
        assert torch.equal(panoptic.mask(ours), multiview.mask(theirs))
    assert torch.allclose(panoptic.points.xyz, multiview.points.xyz, atol=1e-5)
    assert (panoptic.points.rgb - multiview.points.rgb).abs().max() <= 0.5 / 255 + 1e-6
    assert multiview.extent == pytest.approx(panoptic.extent, rel=1e-5)
    assert multiview.effects == panoptic.effects


def test_export_renumbers_the_test_cameras_as_the_multiview_loader_numbers_folders(
    tiny_synth_copy: Path, tmp_path: Path
):
    # Panoptic camera ids 5, 7, 9, ... become cam00, cam01, cam02, ...: ids 0..30 once exported
    for name in ("train_meta.json", "test_meta.json"):
        meta = json.loads((tiny_synth_copy / name).read_text())
        meta["cam_id"] = [[5 + 2 * camera_id for camera_id in row] for row in meta["cam_id"]]
        (tiny_synth_copy / name).write_text(json.dumps(meta))
    _declare(tiny_synth_copy, test_cameras=[5, 25, 35, 65])
    source = load_scene(tiny_synth_copy)
    assert _held_out(source) == [5, 25, 35, 65]
    assert _held_out(load_scene(export_multiview(source, tmp_path / "out"))) == JUGGLE_TEST_CAMERAS


def test_the_option_overrides_the_declared_test_cameras_and_the_default_is_0_10_20_30(
    multiview_copy: Path,
):
    assert _held_out(load_scene(multiview_copy, test_cameras=[3])) == [3]
    _declare(multiview_copy, test_cameras=None)
    assert _held_out(load_scene(multiview_copy)) == [0, 10, 20, 30]


def _held_out(scene: Scene) -> list[int]:
    return [camera.camera_id for camera in scene.test_cameras]


def _declare(root: Path, test_cameras: object) -> None:
    """Set (None: remove) the `test_cameras` field of root/scene.json."""
    path = root / "scene.json"
    declaration = json.loads(path.read_text())
    declaration.pop("test_cameras")
    if test_cameras is not None:
        declaration["test_cameras"] = test_cameras
    path.write_text(json.dumps(declaration))


def _legacy_fingerprint(root: Path) -> str:
    """The fingerprint relaygs gave a multi-view folder before scene.json could set its split."""
    names = [f"sparse/0/{path.name}" for path in sorted((root / "sparse" / "0").iterdir())]
    names += [path.relative_to(root).as_posix() for path in root.glob("cam*/*.png")]
    names += [path.relative_to(root).as_posix() for path in root.glob("seg/cam*/*.png")]
    files = {name: file_record(root / name, root=root).sha256 for name in [*names, "scene.json"]}
    content = digest(
        {"format": "multiview", "options": make_options().content_options(), "files": files}
    )
    return digest({"content": content, "downscale": 1})


def test_a_declared_split_changes_the_fingerprint_and_only_then(multiview_copy: Path):
    # artifacts built when relaygs ignored scene.json's split (same files) must not be reused
    assert load_scene(multiview_copy).fingerprint != _legacy_fingerprint(multiview_copy)
    _declare(multiview_copy, test_cameras=None)
    assert load_scene(multiview_copy).fingerprint == _legacy_fingerprint(multiview_copy)


@pytest.mark.parametrize(
    ("declared", "named"),
    [
        ([0, 99], ["'test_cameras'", "[99]", "0..30", "scene.loader.test_cameras=[0]"]),
        ("0,10", ["'test_cameras'", "camera ids"]),
        ([0, -1], ["'test_cameras'", "camera ids"]),
    ],
)
def test_bad_declared_test_cameras_are_refused(multiview_copy: Path, declared, named):
    _declare(multiview_copy, test_cameras=declared)
    with refused(InputError, "scene.json", *named):
        load_scene(multiview_copy)


def test_export_refuses_a_source_scene_json_that_is_not_an_object(tiny_synth_copy: Path, tmp_path):
    scene = load_scene(tiny_synth_copy)
    (tiny_synth_copy / "scene.json").write_text("[]")
    with refused(InputError, "scene.json"):
        export_multiview(scene, tmp_path / "out")


def _move_camera(meta: dict) -> None:
    meta["w2c"][1][0][0][3] += 0.5  # camera of column 0 moves at frame 1


def _swap_in_a_camera(meta: dict) -> None:
    meta["cam_id"][1][0] = 99  # frame 1 sees camera 99 instead: two cameras miss frames


@pytest.mark.parametrize(
    ("edit", "named"),
    [(_move_camera, ["changes over time", "fixed rig"]), (_swap_in_a_camera, ["5 of the 6"])],
)
def test_export_refuses_a_scene_that_is_no_fixed_rig(tiny_synth_copy: Path, tmp_path, edit, named):
    path = tiny_synth_copy / "train_meta.json"
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))
    scene = load_scene(tiny_synth_copy)
    with refused(InputError, *named):
        export_multiview(scene, tmp_path / "out")
    assert not (tmp_path / "out").exists()


MODEL = ColmapModel(
    cameras={
        1: ColmapCamera(1, "PINHOLE", 64, 48, (50.0, 51.0, 32.0, 24.5)),
        2: ColmapCamera(2, "SIMPLE_RADIAL", 64, 48, (40.0, 31.0, 23.0, 0.0)),
    },
    images={
        3: ColmapImage(3, (0.5, 0.5, -0.5, 0.5), (0.1, -2.0, 3.5), 1, "cam00.png"),
        8: ColmapImage(8, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 2, "dir/cam01 frame.png"),
    },
    xyz=np.random.default_rng(1).normal(size=(20, 3)),
    rgb=np.random.default_rng(1).integers(0, 256, size=(20, 3)).astype(np.uint8),
)


@pytest.mark.parametrize("binary", [True, False])
def test_binary_and_text_models_round_trip(tmp_path: Path, binary: bool):
    write_model(tmp_path, MODEL, binary=binary)
    loaded = read_model(str(tmp_path))  # a path given as text, as load_scene takes it
    assert (loaded.cameras, loaded.images) == (MODEL.cameras, MODEL.images)
    assert np.array_equal(loaded.xyz, MODEL.xyz) and np.array_equal(loaded.rgb, MODEL.rgb)


def test_quaternion_round_trip():
    rng = np.random.default_rng(2)
    for _ in range(50):
        quaternion = rng.normal(size=4)
        quaternion /= np.linalg.norm(quaternion)
        rotation = qvec_to_rotation(quaternion)
        assert np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        recovered = rotation_to_qvec(rotation)
        assert np.allclose(recovered, quaternion * np.sign(quaternion[0]), atol=1e-10)


@pytest.fixture
def multiview_copy(multiview_root: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(multiview_root, tmp_path / "copy"))


def _expect(root: Path, *fragments: str) -> None:
    with refused(InputError, *fragments):
        load_scene(root)


@pytest.mark.parametrize("qvec", [[0.0, 0.0, 0.0, 0.0], [np.nan, 0.0, 0.0, 1.0]])
def test_quaternion_of_no_direction_is_refused(qvec):
    with refused(ValueError, "finite non-zero"):
        qvec_to_rotation(np.array(qvec))


def test_text_model_with_a_byte_order_mark_reads_as_without(tmp_path: Path):
    # Windows editors may start a UTF-8 file with a BOM; COLMAP's "# Camera list" comment
    # must still read as a comment
    write_model(tmp_path, MODEL, binary=False)
    for name in ("cameras.txt", "images.txt", "points3D.txt"):
        path = tmp_path / name
        path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    model = read_model(tmp_path)
    assert (model.cameras, model.images) == (MODEL.cameras, MODEL.images)
    np.testing.assert_array_equal(model.rgb, MODEL.rgb)


def test_binary_images_with_2d_observations_are_read_past_them(tmp_path: Path):
    # COLMAP stores each image's 2D points (x, y as doubles, point3D id as int64) after its
    # name; the writer stores none, so write them here: 3 for the first image, 1 for the next
    write_model(tmp_path, MODEL, binary=True)
    blob = [struct.pack("<Q", len(MODEL.images))]
    for image, observations in zip(MODEL.images.values(), (3, 1), strict=True):
        blob.append(struct.pack("<I7dI", image.image_id, *image.qvec, *image.tvec, image.camera_id))
        blob.append(image.name.encode() + b"\x00" + struct.pack("<Q", observations))
        blob += [struct.pack("<ddq", 1.5 * n, 2.5, n - 1) for n in range(observations)]
    (tmp_path / "images.bin").write_bytes(b"".join(blob))
    assert read_model(tmp_path).images == MODEL.images


def _edit_first_record(path: Path, edit) -> None:
    """Replace the first non-comment line of a text model file with `edit(fields)` joined."""
    lines = path.read_text().splitlines()
    index = next(i for i, line in enumerate(lines) if line and not line.startswith("#"))
    lines[index] = " ".join(edit(lines[index].split()))
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize(("value", "refused"), [(255, False), (256, True), (-1, True)])
def test_text_model_colour_limits_are_0_and_255(tmp_path: Path, value: int, refused: bool):
    write_model(tmp_path, MODEL, binary=False)
    _edit_first_record(tmp_path / "points3D.txt", lambda f: [*f[:4], str(value), *f[5:]])
    if refused:
        with pytest.raises(InputError, match=r"R G B in 0\.\.255"):
            read_model(tmp_path)
    else:
        assert read_model(tmp_path).rgb[0, 0] == value


@pytest.mark.parametrize(
    ("name", "edit", "fragment"),
    [
        ("cameras.txt", lambda f: [f[0], "KANNALA", *f[2:]], "with a known COLMAP model"),
        ("cameras.txt", lambda f: [f[0], f[1], "64.5", *f[3:]], "CAMERA_ID MODEL WIDTH"),
        ("cameras.txt", lambda f: [*f, "32"], "4 PINHOLE params"),
        ("images.txt", lambda f: f[:9], "IMAGE_ID QW QX QY QZ"),
        ("images.txt", lambda f: [f[0], "one", *f[2:]], "IMAGE_ID QW QX QY QZ"),
        ("points3D.txt", lambda f: [f[0], "x", *f[2:]], "POINT3D_ID X Y Z R G B"),
        ("points3D.txt", lambda f: f[:7], "POINT3D_ID X Y Z R G B"),
    ],
    ids=["model", "fractional width", "extra param", "short image", "word qw", "word x", "short"],
)
def test_malformed_text_model_records_are_refused_naming_file_and_line(
    tmp_path: Path, name: str, edit, fragment: str
):
    write_model(tmp_path, MODEL, binary=False)
    _edit_first_record(tmp_path / name, edit)
    with refused(InputError, f"{name} line ", fragment):
        read_model(tmp_path)


def test_an_images_file_without_its_points2d_lines_is_refused_naming_the_line(tmp_path: Path):
    # written by hand with one line per image: the second image's line would be read as the
    # first one's 2D points, and that image silently lost
    write_model(tmp_path, MODEL, binary=False)
    path = tmp_path / "images.txt"
    records = [line for line in path.read_text().splitlines() if line and line[0] != "#"]
    path.write_text("\n".join(records) + "\n")
    with refused(InputError, "images.txt line 2", "POINTS2D", "'cam00.png'"):
        read_model(tmp_path)
    path.write_text("\n".join([records[0], "1.5 2.5 -1 3.0 4.0 7", records[1], ""]) + "\n")
    assert sorted(read_model(tmp_path).images) == [3, 8]  # two observations: read past


def test_folder_without_a_complete_model_is_refused(tmp_path: Path):
    write_model(tmp_path, MODEL, binary=False)
    (tmp_path / "points3D.txt").unlink()
    with refused(InputError, "COLMAP model"):
        read_model(tmp_path)


def _binary_images(name: bytes, observations: int, observation_bytes: int) -> bytes:
    head = struct.pack("<QI7dI", 1, 3, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1)
    return head + name + struct.pack("<Q", observations) + b"\x00" * observation_bytes


@pytest.mark.parametrize(
    ("name", "damage", "named"),
    [
        ("images.bin", lambda data: data[:-4], ["truncated"]),
        ("points3D.bin", lambda data: struct.pack("<Q", 2**40) + data[8:], ["1099511627776"]),
        # after the count (Q) and camera id (i): the model id
        ("cameras.bin", lambda data: data[:12] + struct.pack("<i", 99) + data[16:], ["99"]),
        ("images.bin", lambda _: _binary_images(b"cam00.png", 0, 0)[:-8], ["byte 72"]),
        # 3 observations of 24 bytes declared, 2 present
        ("images.bin", lambda _: _binary_images(b"cam00.png\x00", 3, 48), ["byte 90"]),
        ("cameras.txt", lambda data: b"\xff\xfe" + data, ["not UTF-8", "0xff"]),
    ],
    ids=["truncated", "point count", "model id", "name without nul", "2d points", "not utf-8"],
)
def test_a_damaged_model_file_is_refused_naming_it(tmp_path: Path, name, damage, named):
    write_model(tmp_path, MODEL, binary=name.endswith(".bin"))
    path = tmp_path / name
    path.write_bytes(damage(path.read_bytes()))
    with refused(InputError, name, *named):
        read_model(tmp_path)


def test_test_cameras_beyond_the_camera_folders_are_refused(multiview_root: Path):
    with refused(InputError, "[99]", "scene.loader.test_cameras=[0]", "--test-cameras 0"):
        load_scene(multiview_root, test_cameras=[0, 99])
    with refused(InputError, "scene.loader.test_cameras", "[99]"):
        load_scene(multiview_root, test_cameras=[99], option_prefix="scene.loader.")


def test_a_one_camera_capture_is_told_how_to_hold_out_none(multiview_copy: Path):
    for folder in [*multiview_copy.glob("cam*"), *multiview_copy.glob("seg/cam*")]:
        if folder.name != "cam00":
            shutil.rmtree(folder)
    none = "scene.loader.test_cameras=[] (artifacts commands: --test-cameras '[]')"
    _declare(multiview_copy, test_cameras=[10, 15, 30])  # a split copied from a larger rig
    _expect(multiview_copy, "'test_cameras'", "[10, 15, 30]", "0..0", none)
    _declare(multiview_copy, test_cameras=None)  # the default split holds out camera 0
    _expect(multiview_copy, "no training cameras", "[0]", none)
    assert load_scene(multiview_copy, test_cameras=[]).test_views == []


PYCOLMAP_FIXTURE = Path(__file__).parent / "data" / "pycolmap"
"""A model written by COLMAP's own code (pycolmap 4.2.1, `tools/make_pycolmap_fixture.py`):
rigs and frames files (cam00 and cam01 on one rig), tracks and keypoints included;
expected.json is what pycolmap reads in it."""


def _sorted_points(xyz: np.ndarray, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points ordered by x, then y, then z (expected.json's order)."""
    order = np.lexsort(xyz.T[::-1])
    return xyz[order], rgb[order]


@pytest.mark.parametrize("kind", ["bin", "txt"])
def test_a_model_colmap_wrote_reads_as_colmap_reads_it(kind):
    expected = json.loads((PYCOLMAP_FIXTURE / "expected.json").read_text())
    model = read_model(PYCOLMAP_FIXTURE / kind)
    images = {image.name: image for image in model.images.values()}
    assert set(images) == set(expected["images"])
    for name, want in expected["images"].items():
        image = images[name]
        assert (image.image_id, image.camera_id) == (want["image_id"], want["camera_id"])
        np.testing.assert_allclose(image.qvec, want["qvec"], rtol=0, atol=1e-15)
        np.testing.assert_allclose(image.tvec, want["tvec"], rtol=0, atol=1e-15)
        np.testing.assert_allclose(image.w2c()[:3, :3], want["rotation"], rtol=0, atol=1e-12)
        camera = model.cameras[image.camera_id]
        assert (camera.model, list(camera.params)) == (want["model"], want["params"])
        assert [camera.width, camera.height] == expected["size"]
    xyz, rgb = _sorted_points(model.xyz, model.rgb)
    np.testing.assert_allclose(xyz, expected["xyz"], rtol=0, atol=1e-15)
    assert rgb.tolist() == expected["rgb"]


def test_a_capture_posed_by_a_model_colmap_wrote_loads_with_its_poses(tmp_path):
    expected = json.loads((PYCOLMAP_FIXTURE / "expected.json").read_text())
    width, height = expected["size"]
    for name in expected["images"]:
        for frame in (0, 1):
            path = tmp_path / Path(name).parent / f"frame_{frame:05d}.png"
            path.parent.mkdir(exist_ok=True)
            cv2.imwrite(str(path), np.full((height, width, 3), 40 * frame, dtype=np.uint8))
    shutil.copytree(PYCOLMAP_FIXTURE / "bin", tmp_path / "sparse" / "0")
    scene = load_scene(tmp_path, test_cameras=[1])
    assert scene.num_frames == 2
    assert [c.camera_id for c in scene.train_cameras] == [0, 2]
    cameras = {c.camera_id: c for c in scene.train_cameras + scene.test_cameras}
    for camera_id, name in enumerate(sorted(expected["images"])):  # cam00, cam01, cam02
        want, camera = expected["images"][name], cameras[camera_id]
        np.testing.assert_allclose(camera.K.numpy(), want["K"], rtol=1e-6)
        np.testing.assert_allclose(camera.w2c[:3, :3].numpy(), want["rotation"], atol=1e-6)
        np.testing.assert_allclose(camera.w2c[:3, 3].numpy(), want["tvec"], atol=1e-6)
        assert (camera.width, camera.height) == (width, height)
    xyz, rgb = _sorted_points(scene.points.xyz.double().numpy(), scene.points.rgb.numpy())
    np.testing.assert_allclose(xyz, expected["xyz"], atol=1e-6)
    np.testing.assert_allclose(rgb, np.asarray(expected["rgb"]) / 255.0, atol=1e-6)


def _rewrite_model(root: Path, edit) -> None:
    """Apply `edit` to root's COLMAP model (or take the model it returns) and write it back."""
    folder = root / "sparse" / "0"
    model, binary = read_model(folder), model_suffix(folder) == ".bin"
    model = edit(model) or model
    for path in folder.iterdir():
        path.unlink()
    write_model(folder, model, binary=binary)


def _in_model(edit: Callable[[ColmapModel], None]) -> Callable[[Path], None]:
    """A damage: rewrite the scene's COLMAP model with `edit` applied."""
    return lambda root: _rewrite_model(root, edit)


def _camera_1(params=lambda old: old, **changes) -> Callable[[Path], None]:
    """A damage: change camera 1 of the model (its parameters to `params(old)`)."""

    def edit(model: ColmapModel) -> None:
        camera = model.cameras[1]
        model.cameras[1] = replace(camera, params=params(camera.params), **changes)

    return _in_model(edit)


def _first_image(**changes) -> Callable[[Path], None]:
    """A damage: change the first registered image of the model."""

    def edit(model: ColmapModel) -> None:
        image_id = min(model.images)
        model.images[image_id] = replace(model.images[image_id], **changes)

    return _in_model(edit)


def _rename_cam04_image(model: ColmapModel) -> None:
    image_id = next(i for i, image in model.images.items() if "cam04" in image.name)
    model.images[image_id] = replace(model.images[image_id], name="cam03_copy.png")


def _unlink_frames(folder: str, *frames: int) -> Callable[[Path], None]:
    """A damage: delete the frames (all where none are given) of a camera folder."""

    def unlink(root: Path) -> None:
        for path in sorted((root / folder).iterdir()):
            if not frames or int(path.stem.split("_")[1]) in frames:
                path.unlink()

    return unlink


def _jpeg_beside_png_frame_3(root: Path) -> None:
    # a JPEG copy left beside each camera's PNG frame would otherwise double every camera's
    # frame count, each frame shown twice on a stretched time axis
    for folder in sorted(root.glob("cam*")):
        png = folder / "frame_00003.png"
        cv2.imwrite(str(png.with_suffix(".jpg")), cv2.imread(str(png)))


def _camera_folder_without_image(root: Path) -> None:
    for parent in (root, root / "seg"):
        shutil.copytree(parent / "cam30", parent / "cam31")


BAD_MULTIVIEW = {
    "distortion": (
        _camera_1(model="OPENCV", params=lambda p: (*p, 0.1, 0, 0, 0)),
        ["cameras", "camera 1 (OPENCV)", "distortion"],
    ),
    "fisheye": (
        _camera_1(model="SIMPLE_RADIAL_FISHEYE", params=lambda p: (p[0], p[2], p[3], 0.0)),
        ["cameras", "camera 1", "SIMPLE_RADIAL_FISHEYE"],
    ),
    **{
        f"fx {focal}": (
            _camera_1(params=lambda p, focal=focal: (focal, *p[1:])),
            ["cameras", "camera 1 (PINHOLE)", f"fx = {focal}"],
        )
        for focal in (0.0, -50.0, float("nan"), float("inf"))
    },
    "no points": (
        _in_model(lambda model: replace(model, xyz=model.xyz[:0], rgb=model.rgb[:0])),
        ["sparse/0/points3D.", "non-empty point cloud"],
    ),
    "wider camera": (_camera_1(width=64), ["32x18", "64x18"]),
    "zero qvec": (_first_image(qvec=(0.0, 0.0, 0.0, 0.0)), ["qvec", "quaternion"]),
    "nan tvec": (_first_image(tvec=(float("nan"), 0.0, 4.0)), ["qvec", "tvec"]),
    # inf once cast to float32
    "huge tvec": (_first_image(tvec=(1e39, 0.0, 4.0)), ["qvec", "tvec"]),
    "unknown camera": (_first_image(camera_id=99), ["camera 99"]),
    "two images of a camera": (_in_model(_rename_cam04_image), ["'cam03_copy.png'", "cam03"]),
    "frame missing": (_unlink_frames("cam04", 5), ["cam04", "frame_00005.png", "0..5 in cam00"]),
    "first camera's frames missing": (
        _unlink_frames("cam00", 1, 2, 3, 4),
        ["cam00", "frame_00001.png", "frame_00003.png", "1 more", "0..5 in cam01"],
    ),
    "no frames": (_unlink_frames("cam04"), ["cam04", "frame_XXXXX"]),
    "two files of frame 3": (_jpeg_beside_png_frame_3, ["cam00", "frame_00003.jpg", "frame 3"]),
    "no model": (lambda root: shutil.rmtree(root / "sparse"), ["COLMAP", "sparse/0"]),
    "unregistered folder": (_camera_folder_without_image, ["cam31"]),
}


@pytest.mark.parametrize("case", BAD_MULTIVIEW)
def test_a_bad_multiview_scene_is_refused_naming_what_is_wrong(multiview_copy: Path, case: str):
    damage, named = BAD_MULTIVIEW[case]
    damage(multiview_copy)
    with refused(InputError, *named):
        load_scene(multiview_copy)
