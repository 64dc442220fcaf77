"""Bad scene input: each case is an InputError whose one-line message names file/field/value."""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from refusals import refused
from relaygs.data import load_scene
from relaygs.data.camera import check_intrinsics, check_rigid
from relaygs.data.imageio import image_size, read_mask, read_rgb
from relaygs.errors import InputError


def _edit_meta(root: Path, name: str, edit: Callable[[dict], None]) -> None:
    path = root / name
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))


def _expect(root: Path, *fragments: str, **options) -> str:
    with refused(InputError, *fragments) as caught:
        load_scene(root, **options)
    return str(caught.value)


def test_a_scene_folder_that_cannot_be_read_is_one_line(tmp_path: Path, monkeypatch):
    # chmod 000 on the folder (tests run as root here, whom permissions do not stop)
    exists = Path.exists

    def denied(path: Path, *args, **kwargs) -> bool:
        if path.parent == tmp_path:
            raise PermissionError(13, "Permission denied", str(path))
        return exists(path, *args, **kwargs)

    monkeypatch.setattr(Path, "exists", denied)
    _expect(tmp_path, f"{tmp_path}: cannot read the scene folder (Permission denied)")


def test_missing_or_unknown_scene_folder(tmp_path: Path):
    _expect(tmp_path / "absent", "scene folder: ", "absent does not exist")
    _expect(tmp_path, "unknown scene layout", "train_meta.json")


def _cut_to_60_percent(data: bytes) -> bytes:
    return data[: len(data) * 6 // 10]


def _flip_first_idat_byte(data: bytes) -> bytes:
    at = data.index(b"IDAT") + 4
    return data[:at] + bytes([data[at] ^ 0xFF]) + data[at + 1 :]


def _cut_in_the_first_idat_crc(data: bytes) -> bytes:
    start = data.index(b"IDAT") - 4
    length = int.from_bytes(data[start : start + 4], "big")
    return data[: start + 8 + length + 2]  # its data whole, two of its four CRC bytes


def test_truncated_jpeg_is_refused_and_an_intact_one_loads(tiny_synth_copy: Path):
    png = tiny_synth_copy / "ims" / "7" / "000003.png"
    jpeg = png.with_suffix(".jpg")
    cv2.imwrite(str(jpeg), cv2.imread(str(png)))
    meta = tiny_synth_copy / "train_meta.json"
    meta.write_text(meta.read_text().replace('"7/000003.png"', '"7/000003.jpg"'))
    assert any(view.image_path == jpeg for view in load_scene(tiny_synth_copy).train_views)
    jpeg.write_bytes(_cut_to_60_percent(jpeg.read_bytes()))
    _expect(tiny_synth_copy, "7/000003.jpg: damaged image file", "no JPEG end marker FFD9")


JPEG_VARIANTS = {
    "baseline": ([], b""),
    "progressive": ([cv2.IMWRITE_JPEG_PROGRESSIVE, 1], b""),
    "restart markers": ([cv2.IMWRITE_JPEG_RST_INTERVAL, 1], b""),
    "zero padding": ([], bytes(16)),
    "motion photo": ([], b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 4),
}


@pytest.mark.parametrize("variant", JPEG_VARIANTS, ids=list(JPEG_VARIANTS))
def test_jpeg_size_walks_to_the_end_marker(variant: str):
    """Any intact JPEG gives its size, whatever follows its end marker (a phone's motion photo
    appends a video); cut anywhere before that marker, it is refused as truncated."""
    params, appended = JPEG_VARIANTS[variant]
    pixels = np.random.default_rng(0).integers(0, 256, (24, 40, 3), dtype=np.uint8)
    jpeg = cv2.imencode(".jpg", pixels, params)[1].tobytes()
    assert image_size(jpeg + appended, Path("a.jpg")) == (40, 24)
    for cut in (len(jpeg) - 2, len(jpeg) * 6 // 10, 40):
        with refused(InputError, "a.jpg", "JPEG end marker"):
            image_size(jpeg[:cut], Path("a.jpg"))


def test_a_fill_byte_before_a_jpeg_marker_is_skipped_as_libjpeg_does():
    pixels = np.random.default_rng(0).integers(0, 256, (24, 40, 3), dtype=np.uint8)
    jpeg = cv2.imencode(".jpg", pixels)[1].tobytes()
    frame = jpeg.index(b"\xff\xc0")
    filled = jpeg[:frame] + b"\xff" + jpeg[frame:]  # one fill byte before the frame header
    assert cv2.imdecode(np.frombuffer(filled, np.uint8), cv2.IMREAD_COLOR).shape == (24, 40, 3)
    assert image_size(filled, Path("a.jpg")) == (40, 24)


def test_opengl_axes_are_refused_as_putting_the_scene_behind_the_cameras(tiny_synth_copy: Path):
    # a common pose mistake: OpenGL's camera axes (y up, z backward) for OpenCV's; a cloud
    # around the subject the rig looks at is then behind every camera: a black scene
    def opengl(meta: dict) -> None:
        meta["w2c"] = (np.diag([1.0, -1.0, -1.0, 1.0]) @ np.array(meta["w2c"])).tolist()

    subject = np.random.default_rng(0).uniform(-0.5, 0.5, (50, 7))
    subject[:, 3:] = 0.5
    np.savez(tiny_synth_copy / "init_pt_cld.npz", data=subject)
    load_scene(tiny_synth_copy)  # in OpenCV's axes the rig sees it

    for name in ("train_meta.json", "test_meta.json"):
        _edit_meta(tiny_synth_copy, name, opengl)
    _expect(
        tiny_synth_copy,
        f"{tiny_synth_copy}: none of the point cloud's",
        "points is in front of a training camera and inside its image; expected world→camera",
    )


def test_one_point_in_view_is_enough(tiny_synth_copy: Path):
    scene = load_scene(tiny_synth_copy)
    camera = scene.full_train_views[0].camera
    centre = camera.center.double().numpy()
    ahead = centre + camera.c2w.double().numpy()[:3, 2]  # 1 unit along the optical axis
    data = np.zeros((50, 7))
    data[:, :3] = centre - 5.0 * camera.c2w.double().numpy()[:3, 2]  # behind that camera
    data[0, :3] = ahead
    np.savez(tiny_synth_copy / "init_pt_cld.npz", data=data)
    assert load_scene(tiny_synth_copy).points.xyz.shape[0] >= 1


def _written(write: Callable[[io.BytesIO], None]) -> bytes:
    buffer = io.BytesIO()
    write(buffer)
    return buffer.getvalue()


@pytest.mark.parametrize(
    "content",
    [
        _written(lambda out: np.save(out, np.zeros((5, 7), np.float32))),
        _written(lambda out: np.savez(out, data=np.full((5, 7), None, dtype=object))),
        bytes(range(256)) * 4,
        b"x y z r g b seg\n0 0 0 1 1 1 1\n",
    ],
    ids=[".npy file", "pickled objects", "random bytes", "text"],
)
def test_point_cloud_that_is_not_an_npz_of_numbers(tiny_synth_copy: Path, content: bytes):
    (tiny_synth_copy / "init_pt_cld.npz").write_bytes(content)
    message = _expect(tiny_synth_copy, "init_pt_cld.npz: not a readable .npz point cloud")
    assert "pickle" not in message, message


# a NUL or a lone surrogate (valid JSON) made path.stat() raise a bare ValueError
@pytest.mark.parametrize("name", ["", ".", "3/..", "0/a\0b.png", "0/\ud800.png"])
def test_file_name_that_names_no_file(tiny_synth_copy: Path, name: str):
    _edit_meta(tiny_synth_copy, "train_meta.json", lambda meta: meta["fn"][2].__setitem__(1, name))
    _expect(tiny_synth_copy, f"train_meta.json: field 'fn' at [2][1] is {name!r}")


@pytest.mark.parametrize(
    ("content", "named"),
    [
        ('{"effects": ["nonrigid", "glitter"]}', ["unknown effect 'glitter'"]),
        *[({"effects": v}, ["'effects'", "list of effect names"]) for v in ("x", {"x": 1}, None)],
        *[(text, ["expected a JSON object"]) for text in ('["nonrigid"]', '"nonrigid"', "null")],
    ],
)
def test_a_bad_scene_json_is_refused(tiny_synth_copy: Path, content, named: list):
    text = content if isinstance(content, str) else json.dumps(content)
    (tiny_synth_copy / "scene.json").write_text(text)
    _expect(tiny_synth_copy, "scene.json", *named)


def test_a_scene_without_scene_json_declares_no_effects(tiny_synth_copy: Path):
    (tiny_synth_copy / "scene.json").unlink()
    assert load_scene(tiny_synth_copy).effects == frozenset()


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ({"downscale": 0}, ["downscale", ">= 1"]),
        ({"downscale": 1.5}, ["downscale", ">= 1"]),
        ({"max_points": 0}, ["max_points", ">= 1"]),
        ({"cache_mb": -1}, ["cache_mb", "> 0"]),
        ({"cache_mb": float("inf")}, ["cache_mb", "inf"]),
        ({"cache_mb": 1e308}, ["cache_mb", "1e+308"]),
        ({"test_cameras": [99]}, ["test_cameras", "[99]"]),
        ({"test_cameras": [1, 99]}, ["[99]", "test_cameras=[1]", "--test-cameras 1)"]),
        ({"test_cameras": range(31)}, ["no training cameras", "--test-cameras '[]'"]),
        ({"effects": ["sparkle"]}, ["unknown effect 'sparkle'"]),
    ],
)
def test_bad_loader_options(tiny_synth_scene: Path, options: dict, named: list):
    _expect(tiny_synth_scene, *named, **options)


@pytest.mark.parametrize(
    ("entries", "problem"),
    [
        ({(0, 0): -2.0, (1, 1): 0.0}, "fx = -2.0, fy = 0.0"),
        # the projection's backward takes fx/depth²: NaN gradients beyond 1e20
        ({(0, 0): 1e36}, "fx = 1e+36"),
        ({(0, 2): float("inf")}, "cx = inf"),
        ({(0, 1): float("nan")}, "K[0][1] = nan"),
        ({(2, 0): 0.5}, "last row [0.5, 0.0, 1.0]"),
        # the renderer models no skew: dropping it would train on wrong rays
        ({(0, 1): 1e6}, "skew K[0][1] = 1000000.0, K[1][0] = 0.0"),
        ({(1, 0): 5.0}, "skew K[0][1] = 0.0, K[1][0] = 5.0"),
        # intrinsics meant for another resolution: well-formed, but they would train a wrong scene
        ({(0, 2): 3200.0}, "cx = 3200.0 outside 0..32"),
        ({(1, 2): -1.0}, "cy = -1.0 outside 0..18"),
        ({(0, 2): 32.0}, "cx = 32.0 outside 0..32"),  # on the edge, as twice the resolution gives
    ],
)
def test_intrinsics_errors_name_the_bad_values(entries: dict, problem: str):
    K = np.array([[20.0, 0.0, 16.0], [0.0, 20.0, 9.0], [0.0, 0.0, 1.0]])
    for at, value in entries.items():
        K[at] = value
    with refused(InputError, f"cam.txt: camera 3 has {problem}; expected", "inside the 32x18"):
        check_intrinsics(K, "cam.txt: camera 3", size=(32, 18))


def test_a_small_skew_and_a_centre_near_the_edge_are_accepted():
    K = np.array([[2000.0, 1.9, 31.5], [-1.9, 2000.0, 0.5], [0.0, 0.0, 1.0]])
    check_intrinsics(K, "cam.txt: camera 3", size=(32, 18))  # rounding in a calibration file
    K[0, 2] = 3200.0
    check_intrinsics(K, "cam.txt: camera 3")  # the image's size unknown: nothing to compare
    K[0, 1] = 2.1  # beyond a thousandth of the focal length
    with refused(InputError, "has skew K"):
        check_intrinsics(K, "cam.txt: camera 3")


def test_a_batch_of_poses_names_the_first_bad_one_and_non_finite_entries():
    w2c = np.tile(np.eye(4), (2, 3, 1, 1))
    w2c[1, 2, 0, 3] = np.nan
    with refused(InputError, "poses at [1][2] has entries not finite", "[[1.0, 0.0, 0.0, nan]"):
        check_rigid(w2c, "poses")
    w2c[1, 2] = np.eye(4)
    w2c[0, 1, 3] = [0.0, 0.0, 1.0, 1.0]
    with refused(InputError, "poses at [0][1]", "[0.0, 0.0, 1.0, 1.0]"):
        check_rigid(w2c, "poses")


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    ("data", "name", "named"),
    [
        (PNG_SIGNATURE + b"\x00\x00\x00\x0dIHDR\x00\x00", "a.png", "truncated PNG header"),
        (PNG_SIGNATURE + b"\x00" * 16, "a.png", "truncated PNG header"),
        (b"\xff\xd8\xff\xc0\x00\x02\xff\xd9", "a.jpg", "no JPEG frame header found"),
    ],
    ids=["cut in IHDR", "no IHDR first", "JPEG frame header cut short"],
)
def test_an_image_header_cut_short_has_no_size(data: bytes, name: str, named: str):
    with refused(InputError, name, named):
        image_size(data, Path(name))


def test_files_opencv_cannot_decode_are_refused_by_the_pixel_readers(tmp_path: Path):
    path = tmp_path / "frame.png"
    path.write_bytes(b"not an image at all")
    with pytest.raises(InputError, match=r"frame\.png: cannot decode image"):
        read_rgb(path, 4, 3)
    with pytest.raises(InputError, match=r"frame\.png: cannot decode mask image"):
        read_mask(path, 4, 3)


def test_float_images_are_refused_not_scaled_as_integers(tmp_path: Path):
    path = tmp_path / "frame.tiff"
    assert cv2.imwrite(str(path), np.full((3, 4, 3), 0.5, np.float32))
    with refused(InputError, "float32"):
        read_rgb(path, 4, 3)


TRAIN, TEST, IMAGE = "train_meta.json", "test_meta.json", "ims/7/000003.png"
MASK = "seg/7/000003.png"
NAN = float("nan")
SMALL_PNG = cv2.imencode(".png", np.zeros((10, 20, 3), np.uint8))[1]


def _put(name: str, at: tuple, value: object) -> Callable[[Path], None]:
    """A damage: set the entry of meta file `name` at the index path `at` to `value`."""

    def edit(meta: dict) -> None:
        for index in at[:-1]:
            meta = meta[index]
        meta[at[-1]] = value

    return lambda root: _edit_meta(root, name, edit)


def _edit(name: str, edit: Callable[[dict], object]) -> Callable[[Path], None]:
    """A damage: apply `edit` to meta file `name`."""
    return lambda root: _edit_meta(root, name, edit)


def _write(name: str, content: bytes | np.ndarray) -> Callable[[Path], None]:
    """A damage: replace the scene file `name` with `content`."""
    return lambda root: (root / name).write_bytes(bytes(content))


def _damage(name: str, damage: Callable[[bytes], bytes]) -> Callable[[Path], None]:
    """A damage: replace the scene file `name` with `damage` of its bytes."""
    return lambda root: (root / name).write_bytes(damage((root / name).read_bytes()))


def _points(data: np.ndarray, key: str = "data") -> Callable[[Path], None]:
    """A damage: replace the point cloud's archive with one holding `data` as `key`."""
    return lambda root: np.savez(root / "init_pt_cld.npz", **{key: data})


def _scale_rotation(meta: dict) -> None:
    pose = meta["w2c"][0][3]
    pose[:3] = [[2.0 * value for value in line[:3]] + line[3:] for line in pose[:3]]


def _mirror_z(meta: dict) -> None:
    # diag(1, 1, -1) · R is orthonormal (R Rᵀ = I) but has det -1: a mirror, not a rotation
    pose = meta["w2c"][1][2]
    pose[2] = [-value for value in pose[2][:3]] + pose[2][3:]


def _flatten_k(meta: dict) -> None:
    meta["k"] = [[[value for line in k for value in line] for k in row] for row in meta["k"]]


def _k_for_twice_the_resolution(meta: dict) -> None:
    meta["k"][1][2][:2] = [[2.0 * value for value in row] for row in meta["k"][1][2][:2]]


def _share_a_train_camera(root: Path) -> None:
    shared = json.loads((root / TRAIN).read_text())["cam_id"][0][1]
    _edit_meta(root, TEST, lambda meta: [row.__setitem__(0, shared) for row in meta["cam_id"]])


def _replace_by_folder(root: Path) -> None:
    (root / TRAIN).unlink()
    (root / TRAIN).mkdir()


def _cloud_with(row: int, column: int, value: float) -> np.ndarray:
    """A random [50,7] cloud (float64: 1e300 is finite until the cast) with one entry set."""
    data = np.random.default_rng(0).random((50, 7))
    data[row, column] = value
    return data


def _mask_as_jpeg(root: Path) -> None:
    mask = root / "seg" / "7" / "000003.png"
    cv2.imwrite(str(mask.with_suffix(".jpg")), cv2.imread(str(mask)))
    mask.unlink()


BAD_SCENES = {
    "no test meta": (lambda root: (root / TEST).unlink(), [TEST, "test_cameras=", "--test-"]),
    "malformed json": (_write(TRAIN, b'{"w": 32, "h": '), [TRAIN, "JSON", "line 1"]),
    "meta not an object": (_write(TRAIN, b"[1, 2, 3]"), [TRAIN, "JSON object"]),
    "meta is a folder": (_replace_by_folder, [TRAIN, "folder"]),
    "frames per field": (_edit(TRAIN, lambda meta: meta["k"].pop()), [TRAIN, "'k'", "T=5", "T=6"]),
    "cameras per field": (_edit(TEST, lambda m: [r.pop() for r in m["w2c"]]), [TEST, "C=3", "C=4"]),
    "frames per file": (
        _edit(TEST, lambda meta: [meta[field].pop() for field in ("k", "w2c", "fn", "cam_id")]),
        [TEST, "T=5", "T=6"],
    ),
    "k flattened": (_edit(TRAIN, _flatten_k), [TRAIN, "'k'", "[T][C][3][3]"]),
    "zero fx": (_put(TRAIN, ("k", 2, 1, 0, 0), 0.0), [TRAIN, "'k' at [2][1]", "column 1", "fx"]),
    "zero fy": (_put(TEST, ("k", 4, 0, 1, 1), 0.0), [TEST, "'k' at [4][0]", "fy = 0.0"]),
    "k of another size": (_edit(TRAIN, _k_for_twice_the_resolution), [TRAIN, "[1][2]", "outside"]),
    "scaled rotation": (_edit(TEST, _scale_rotation), [TEST, "'w2c' at [0][3]", "orthonormal"]),
    "mirrored pose": (_edit(TEST, _mirror_z), [TEST, "'w2c' at [1][2]", "det -1"]),
    "nan w2c": (_put(TRAIN, ("w2c", 2, 0, 1, 3), NAN), [TRAIN, "'w2c'", "float32"]),
    # finite as JSON's float64, inf once cast to float32
    "huge w2c": (_put(TRAIN, ("w2c", 0, 0, 0, 3), 1e39), [TRAIN, "'w2c'", "float32"]),
    "w2c text": (_put(TRAIN, ("w2c",), "identity"), [TRAIN, "'w2c'", "[T][C][4][4]"]),
    "zero w": (_put(TRAIN, ("w",), 0), [TRAIN, "'w'", ">= 1"]),
    "null h": (_put(TRAIN, ("h",), None), [TRAIN, "'h'", "None"]),
    "no k": (_edit(TRAIN, lambda meta: meta.pop("k")), [TRAIN, "'k'", "[T][C][3][3]"]),
    "no w": (_edit(TRAIN, lambda meta: meta.pop("w")), [TRAIN, "'w'"]),
    "wider test images": (_put(TEST, ("w",), 33), [TEST, "33x18", TRAIN, "32x18"]),
    # its principal points then lie outside the smaller image: the size is what to fix
    "lower test images": (_put(TEST, ("h",), 8), [TEST, "32x8", TRAIN]),
    "empty fn": (_put(TRAIN, ("fn",), []), [TRAIN, "'fn'", "[T][C]"]),
    "fn of numbers": (_put(TRAIN, ("fn",), [[1, 2]]), [TRAIN, "'fn'", "[T][C]"]),
    "ragged fn": (_edit(TRAIN, lambda meta: meta["fn"][1].pop()), [TRAIN, "'fn'"]),
    "escaping name": (_put(TRAIN, ("fn", 2, 1), "../../../etc/passwd"), ["../../../etc/passwd"]),
    "absolute name": (_put(TRAIN, ("fn", 0, 0), "/x.png"), ["'/x.png'"]),
    "huge camera id": (_put(TRAIN, ("cam_id", 0, 0), 1e30), [TRAIN, "'cam_id'", "2147483647"]),
    "camera twice": (_put(TRAIN, ("cam_id", 2, 1), 1), [TRAIN, "'cam_id'", "columns 0 and 1 of"]),
    "test camera trains": (_share_a_train_camera, [TEST, TRAIN]),
    "png cut short": (_damage(IMAGE, _cut_to_60_percent), [f"{IMAGE}: damaged", "IDAT is cut"]),
    "png byte flipped": (_damage(IMAGE, _flip_first_idat_byte), [IMAGE, "IDAT fails its CRC"]),
    "png header only": (_damage(IMAGE, lambda data: data[:33]), [IMAGE, "no IEND chunk"]),
    "png without idat": (_damage(IMAGE, lambda d: d[:33] + d[-12:]), [IMAGE, "no IDAT image"]),
    "mask cut short": (_damage(MASK, _cut_to_60_percent), [f"{MASK}: damaged", "IDAT is cut"]),
    "cut in a crc": (_damage(IMAGE, _cut_in_the_first_idat_crc), [IMAGE, "cut short: truncated"]),
    "undecodable image": (_write(IMAGE, b"this is not an image"), [IMAGE, "image"]),
    "empty image": (_write(IMAGE, b""), [IMAGE, "empty"]),
    "missing image": (lambda root: (root / IMAGE).unlink(), ["000003.png", "No such file"]),
    "no point cloud": (lambda root: (root / "init_pt_cld.npz").unlink(), ["init_pt_cld.npz"]),
    "no points": (_points(np.zeros((0, 7), np.float32)), ["init_pt_cld.npz", "non-empty"]),
    "complex points": (_points(np.ones((5, 7), np.complex64)), ["init_pt_cld.npz", "complex64"]),
    # colours stored as 0..255 instead of 0..1
    "colours 0..255": (_points(_cloud_with(7, 4, 255.0)), ["init_pt_cld.npz", "[0, 1]"]),
    "nan point": (_points(_cloud_with(3, 1, np.nan)), ["init_pt_cld.npz", "not finite"]),
    "huge point": (_points(_cloud_with(3, 1, 1e300)), ["init_pt_cld.npz", "in float32"]),
    "six columns": (_points(np.zeros((5, 6), np.float32)), ["init_pt_cld.npz", "[N,7]"]),
    "no data array": (_points(np.zeros((5, 7)), key="points"), ["missing array 'data'"]),
    "small image": (
        _write("ims/4/000001.png", SMALL_PNG),
        ["000001.png", "20x10", "expected 32x18"],
    ),
    "mask as jpeg": (_mask_as_jpeg, ["seg/7/000003.png", "found 000003.jpg beside it"]),
}


@pytest.mark.parametrize("case", BAD_SCENES)
def test_a_bad_scene_file_is_refused_naming_the_file_and_field(tiny_synth_copy: Path, case: str):
    damage, named = BAD_SCENES[case]
    damage(tiny_synth_copy)
    _expect(tiny_synth_copy, *named)
