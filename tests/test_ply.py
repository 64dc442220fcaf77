"""`python -m relaygs.artifacts ply`: a stored model as 3DGS PLY files, one per frame."""

import numpy as np
import pytest
import torch

from refusals import refused
from relaygs.commands.artifacts import main
from relaygs.data.scene import frame_time
from relaygs.errors import InputError, RelayGSError
from relaygs.model import MAX_LOG_SCALE
from relaygs.pipeline import ArtifactStore, artifact_key
from relaygs.ply import ply_columns, write_frame_plys
from relaygs.train.model_render import ModelRenderer
from relaygs.train.render import Part, splat
from relaygs.train.scene_model import SceneModel

END_HEADER = b"end_header\n"


def _read_ply(path):
    """(header lines, rows as a structured array) of a binary little-endian float PLY."""
    data = path.read_bytes()
    end = data.index(END_HEADER) + len(END_HEADER)
    lines = data[:end].decode("ascii").splitlines()
    assert lines[:2] == ["ply", "format binary_little_endian 1.0"]
    (count,) = [int(line.split()[2]) for line in lines if line.startswith("element vertex ")]
    names = [line.split()[2] for line in lines if line.startswith("property float ")]
    rows = np.frombuffer(data[end:], dtype=[(name, "<f4") for name in names], count=count)
    assert len(data) == end + rows.nbytes  # nothing after the rows
    return lines, rows


def _columns(rows, *names):
    return torch.from_numpy(np.stack([rows[name] for name in names], axis=1))


def _part_from(rows):
    """The Gaussians of a 3DGS PLY as one Part: f_rest holds every red coefficient, then
    every green, then every blue."""
    rest = [name for name in rows.dtype.names if name.startswith("f_rest_")]
    bases = len(rest) // 3 + 1
    sh_rest = _columns(rows, *rest).reshape(-1, 3, bases - 1).transpose(1, 2)
    sh = torch.cat([_columns(rows, "f_dc_0", "f_dc_1", "f_dc_2").unsqueeze(1), sh_rest], dim=1)
    return Part(
        "ply",
        None,
        _columns(rows, "x", "y", "z"),
        _columns(rows, "scale_0", "scale_1", "scale_2"),
        _columns(rows, "rot_0", "rot_1", "rot_2", "rot_3"),
        _columns(rows, "opacity")[:, 0],
        sh,
        frozen=True,
    )


@pytest.mark.parametrize(
    ("fixture", "frame", "active_degree"),
    [
        ("stage_decoupled", 0, None),  # the decoupled movers show at frame 0 only
        ("stage_decoupled", 5, None),
        ("stage_relayed", 1, None),  # segment 0's copy
        ("stage_relayed", 6, None),  # segment 1's
        ("stage_deformed", 5, None),  # moved by the field, γ on the copies
        ("stage_deformed", 2, 1),  # a model stopped before its last SH bands: zero in the file
    ],
)
def test_a_frames_ply_renders_what_the_model_renders_at_that_frame(
    request, stage_scene, tmp_path, fixture, frame, active_degree
):
    model = SceneModel.from_artifact(request.getfixturevalue(fixture))
    if active_degree is not None:
        model.background.active_sh_degree = model.foreground.active_sh_degree = active_degree
    (path,) = write_frame_plys(model, tmp_path, [frame], progress=False)
    assert path == tmp_path / f"{frame:06d}.ply"
    _, rows = _read_ply(path)
    renderer = ModelRenderer(model)
    parts = renderer.parts_at(frame_time(frame, model.num_frames))
    assert len(rows) == sum(part.count for part in parts) > 0
    degree = model.foreground.max_sh_degree  # the model's full degree, as 3DGS's loader wants
    assert sum(name.startswith("f_rest_") for name in rows.dtype.names) == 3 * (degree + 1) ** 2 - 3
    camera = stage_scene.test_views[0].camera  # no colour affine: the file has none
    expected = renderer.render([camera], frame_time(frame, model.num_frames))[0]
    from_file = splat([_part_from(rows)], [camera], degree, **model.blur()).images[0].clamp(0, 1)
    assert torch.allclose(from_file, expected, atol=1e-5)


def test_properties_follow_the_3dgs_layout_and_order():
    n, bases = 2, 9  # SH degree 2
    sh = torch.arange(n * bases * 3, dtype=torch.float32).reshape(n, bases, 3)
    quats = torch.tensor([[2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 3.0, 4.0]])
    means, log_scales = torch.randn(n, 3), torch.tensor([[0.5, -2.0, 1e3], [-1.0, 0.0, 3.0]])
    part = Part("p", None, means, log_scales, quats, torch.tensor([-1.0, 2.0]), sh)
    columns = ply_columns([part], sh_degree=3)  # degree 3 has 16 bases: 7 more, zero
    rest = [f"f_rest_{i}" for i in range(3 * 15)]
    assert list(columns) == [
        *("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"),
        *rest,
        *("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"),
    ]
    for channel in range(3):
        assert torch.equal(columns[f"f_dc_{channel}"], sh[:, 0, channel])
        for basis in range(1, 16):  # all red coefficients first, then green, then blue
            expected = sh[:, basis, channel] if basis < bases else torch.zeros(n)
            assert torch.equal(columns[f"f_rest_{channel * 15 + basis - 1}"], expected)
    assert torch.equal(columns["nx"], torch.zeros(n))
    assert torch.equal(columns["opacity"], torch.tensor([-1.0, 2.0]))  # logits, as stored
    assert torch.equal(columns["scale_1"], log_scales[:, 1])  # log scales, as stored
    capped = torch.tensor([MAX_LOG_SCALE, 3.0])  # as the renderer caps them
    assert torch.equal(columns["scale_2"], capped)
    unit = torch.stack([columns[f"rot_{i}"] for i in range(4)], dim=1)
    assert torch.allclose(unit, torch.tensor([[1.0, 0, 0, 0], [0, 0, 0.6, 0.8]]))  # wxyz


def test_a_frame_outside_the_model_or_a_value_not_finite_writes_nothing(stage_relayed, tmp_path):
    model = SceneModel.from_artifact(stage_relayed)
    with refused(InputError, "frame 8", "0..7"):
        write_frame_plys(model, tmp_path, [0, 8], progress=False)
    later_copy = int((model.foreground.buffers["segment"] == 1).nonzero()[0])
    model.foreground.params["means"].data[later_copy, 1] = float("inf")  # shown from frame 4
    with refused(RelayGSError, "frame 4", "property y"):
        write_frame_plys(model, tmp_path, range(8), progress=False)
    assert not list(tmp_path.iterdir())  # frames 0-3 were written, then removed


def test_a_frame_without_gaussians_is_an_empty_file(stage_decoupled, tmp_path):
    model = SceneModel.from_artifact(stage_decoupled)
    model.background = model.background.subset(torch.zeros(0, dtype=torch.long))
    (path,) = write_frame_plys(model, tmp_path, [5], progress=False)  # the movers show at 0 only
    lines, rows = _read_ply(path)
    assert "element vertex 0" in lines and len(rows) == 0


def _ply_cli(capsys, store, key, *args):
    try:
        code = main(["--root", str(store.root), "ply", key[:8], *args])
    except SystemExit as stop:  # a malformed value: argparse's usage error
        code = stop.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    ("store_dir", "outputs"),
    [("run outputs/artifacts", "run outputs"), ("store", "elsewhere/outputs")],
)
def test_the_command_writes_the_chosen_frames_into_a_folder_named_after_the_model(
    stage_deformed, tmp_path, capsys, monkeypatch, store_dir, outputs
):
    """A run's store (<paths.outputs>/artifacts) exports beside itself, another into ./outputs."""
    store = ArtifactStore(tmp_path / store_dir)
    key = artifact_key("deform", 1, {"steps": 20}, "juggle", [])
    store.get_or_build("deform", key, lambda: stage_deformed, config={}, lineage=[])
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    code, printed, _ = _ply_cli(capsys, store, key, "--frame-stride", "3")
    out = tmp_path / outputs / "ply" / f"deform-{key[:16]}"
    assert (code, printed) == (0, f"deform {key[:16]}: 3 PLY file(s) in {out}\n")
    assert sorted(p.name for p in out.iterdir()) == ["000000.ply", "000003.ply", "000006.ply"]
    assert list(tmp_path.rglob("ply")) == [out.parent]  # and nowhere else
    chosen = tmp_path / "chosen"
    code, _, _ = _ply_cli(capsys, store, key, "--frame", "7", "--frame", "2", "--out", str(chosen))
    assert code == 0 and sorted(p.name for p in chosen.iterdir()) == ["000002.ply", "000007.ply"]


@pytest.mark.parametrize(
    ("args", "status", "message"),
    [
        (["--frame", "8"], 1, "frame 8 is not in the model: its frames are 0..7"),
        (["--frame", "-1"], 1, "frame -1 is not in the model"),
        (["--frame-stride", "0"], 2, "--frame-stride: expected an integer >= 1, got '0'"),
        (["--frame", "1", "--frame-stride", "4"], 2, "--frame-stride: --frame names the frames"),
    ],
)
def test_bad_ply_options_fail_in_one_line(stored_deform, tmp_path, capsys, args, status, message):
    store, key = stored_deform
    out = tmp_path / "ply"
    code, _, err = _ply_cli(capsys, store, key, *args, "--out", str(out))
    assert code == status and message in err and err.count("\n") == 1
    assert not out.exists() or not any(out.iterdir())
