"""`python -m relaygs.artifacts render`: a stored model's frames and videos over time, and
videos along a camera path."""

import itertools

import cv2
import numpy as np
import pytest
import torch

from refusals import refused
from relaygs.camera_path import path_cameras
from relaygs.commands.artifacts import main
from relaygs.data import load_scene
from relaygs.data.scene import frame_time
from relaygs.error_map import error_image
from relaygs.errors import InputError
from relaygs.pipeline.keys import artifact_key
from relaygs.renders import RenderSettings, write_renders
from relaygs.train.model_render import ModelRenderer
from relaygs.train.scene_model import SceneModel


@pytest.fixture
def render(stored_deform, stage_scene_path, capsys):
    """`artifacts render` of the stored deform model on the stage scene: (code, stdout, stderr)."""
    store, key = stored_deform

    def run(*args, scene=stage_scene_path):
        try:
            code = main(
                ["--root", str(store.root), "render", key[:8], "--scene", str(scene), *args]
            )
        except SystemExit as stop:  # a malformed value: argparse's usage error
            code = stop.code
        return (code, *capsys.readouterr())

    return run


def _bgr(image):
    rgb = (image.clamp(0.0, 1.0) * 255.0).round().byte().numpy()
    return rgb[..., ::-1]


def test_render_writes_each_frame_beside_the_truth_and_a_video_per_camera(
    render, stage_scene_path, stage_deformed, tmp_path
):
    out = tmp_path / "renders"
    code, printed, _ = render("--frame-stride", "3", "--truth", "--out", str(out))
    assert code == 0
    scene = load_scene(stage_scene_path)
    renderer = ModelRenderer(SceneModel.from_artifact(stage_deformed))
    frames = [0, 3, 6]
    for camera_id in (0, 10, 15, 30):  # the scene's test cameras
        assert f"camera {camera_id}: 3 frame(s)" in printed
        folder = out / f"cam{camera_id:02d}"
        assert sorted(p.name for p in folder.iterdir()) == [f"{f:06d}.png" for f in frames]
        for frame in frames:
            view = next(v for v in scene.views_at(frame, "test") if v.camera.camera_id == camera_id)
            expected = renderer.render([view.camera], view.time)[0]
            written = cv2.imread(str(folder / f"{frame:06d}.png"))
            width = view.camera.width
            assert written.shape == (view.camera.height, 2 * width, 3)
            np.testing.assert_array_equal(written[:, :width], _bgr(expected))
            np.testing.assert_array_equal(written[:, width:], _bgr(scene.image(view)))
        video = cv2.VideoCapture(str(out / f"cam{camera_id:02d}.mp4"))
        assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 3
        assert int(video.get(cv2.CAP_PROP_FRAME_WIDTH)) == 2 * scene.test_cameras[0].width
        height = scene.test_cameras[0].height
        assert height % 2 == 1  # odd: the video repeats the last row rather than dropping it
        assert int(video.get(cv2.CAP_PROP_FRAME_HEIGHT)) == height + 1
    assert not list(out.glob(".*partial*"))


def test_render_defaults_to_a_folder_named_after_the_model_picks_cameras_refuses_a_file(
    render, stored_deform, tmp_path, monkeypatch, tiny_synth_scene
):
    key = stored_deform[1]
    monkeypatch.chdir(tmp_path)
    code, printed, _ = render("--frame-stride", "4")
    out = tmp_path / "outputs" / "renders" / f"deform-{key[:16]}"
    assert code == 0 and f"rendered into {out}\n" in printed
    assert len(list((out / "cam00").glob("*.png"))) == 2 and (out / "cam00.mp4").is_file()
    out = tmp_path / "renders"
    args = ["--camera", "3", "--no-video", "--out", str(out)]
    assert render(*args)[0] == 0
    assert sorted(p.name for p in out.iterdir()) == ["cam03"]
    assert len(list((out / "cam03").glob("*.png"))) == 8
    # a file where the folder goes, or a scene of other length, is refused
    blocker = tmp_path / "file"
    blocker.write_text("keep me")
    code, _, err = render("--out", str(blocker))
    assert code == 1 and f"--out: {blocker} is not a folder" in err
    assert blocker.read_text() == "keep me"
    code, _, err = render("--out", str(tmp_path / "r"), scene=tiny_synth_scene)
    assert code == 1 and "trained on 8 frames but" in err and "has 6" in err


def test_render_puts_other_models_beside_with_their_error_images(
    render, stored_deform, stage_scene_path, stage_deformed, stage_decoupled, tmp_path
):
    store, key = stored_deform
    other = artifact_key("decouple", 1, {"steps": 2}, "juggle", [])
    store.get_or_build("decouple", other, lambda: stage_decoupled, config={}, lineage=[])
    args = ["--camera", "10", "--frame-stride", "5", "--error", "--no-video", "--out"]
    alone, beside = tmp_path / "alone", tmp_path / "beside"
    assert render(*args, str(alone))[0] == 0
    with_others = ["--beside", other[:8], "--truth", *args, str(beside)]
    code, printed, _ = render(*with_others)
    assert code == 0
    assert (
        f"deform {key[:16]}, decouple {other[:16]} rendered side by side into {beside}" in printed
    )
    scene = load_scene(stage_scene_path)
    view = next(v for v in scene.views_at(5, "all") if v.camera.camera_id == 10)
    truth = scene.image(view)
    renders = [
        ModelRenderer(SceneModel.from_artifact(a)).render([view.camera], view.time)[0]
        for a in (stage_deformed, stage_decoupled)
    ]
    errors = [error_image(render, truth) for render in renders]
    written = cv2.imread(str(alone / "cam10" / "000005.png"))  # without --truth: no truth panel
    np.testing.assert_array_equal(written, _bgr(torch.cat([renders[0], errors[0]], dim=1)))
    assert len(np.unique(written[:, truth.shape[1] :].reshape(-1, 3), axis=0)) > 8  # it varies
    written = cv2.imread(str(beside / "cam10" / "000005.png"))
    np.testing.assert_array_equal(written, _bgr(torch.cat([*renders, truth, *errors], dim=1)))
    assert not np.array_equal(_bgr(renders[0]), _bgr(renders[1]))  # two models, two renders


USAGE = 2  # a usage error: a malformed value or options that contradict each other


@pytest.mark.parametrize(
    ("args", "status", "message"),
    [
        (["--camera", "99"], 1, "camera 99 is not in "),
        (["--beside", "ffff"], 1, "no artifact with key starting 'ffff'"),
        (["--fps", "0"], USAGE, "--fps: expected a positive number, got '0'"),
        (["--fps", "nan"], USAGE, "--fps: expected a positive number, got 'nan'"),
        (["--fps", "fast"], USAGE, "--fps: expected a positive number, got 'fast'"),
        (["--frame-stride", "0"], USAGE, "--frame-stride: expected an integer >= 1, got '0'"),
        (["--device", "mps"], USAGE, "--device: expected cpu, cuda or cuda:N, got 'mps'"),
        (["--path", "0"], USAGE, "--path: expected an integer >= 1, got '0'"),
        (["--path", "2", "--path-frame", "8"], 1, "render path frame 8 is not in "),
        (["--path", "2", "--truth"], USAGE, "--truth: a camera path (--path) has no ground"),
        (["--path", "2", "--frame-stride", "2"], USAGE, "--frame-stride: a camera path (--path)"),
        (["--path-frame", "1"], USAGE, "--path-frame needs --path N (a camera path of N views) ("),
        (["--path", "2", "--camera", "99"], 1, "camera 99 is not in "),
    ],
)
def test_bad_render_options_fail_in_one_line(render, tmp_path, args, status, message):
    out = tmp_path / "renders"
    code, _, err = render(*args, "--out", str(out))
    assert code == status and message in err and err.count("\n") == 1
    assert (code == USAGE) == ("render --help)" in err)  # usage errors say where help is
    assert not out.exists() or not any(out.rglob("*.png"))


def test_an_interrupted_render_leaves_no_video(stage_scene, stage_deformed, tmp_path, monkeypatch):
    calls = []
    original = ModelRenderer.render

    def failing(self, cameras, time):
        calls.append(time)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return original(self, cameras, time)

    monkeypatch.setattr(ModelRenderer, "render", failing)
    model = SceneModel.from_artifact(stage_deformed)
    with pytest.raises(KeyboardInterrupt):
        write_renders(stage_scene, model, tmp_path, RenderSettings(), progress=False)
    assert len(list((tmp_path / "cam00").glob("*.png"))) == 2
    assert not list(tmp_path.glob("*.mp4")) and not list(tmp_path.glob(".*"))


@pytest.mark.parametrize("blocked", ["cam00", "cam00.mp4"])
def test_a_path_in_the_way_of_a_render_is_named_and_no_partial_video_is_left(
    stage_scene, stage_deformed, tmp_path, blocked
):
    if blocked.endswith(".mp4"):
        (tmp_path / blocked).mkdir()
    else:
        (tmp_path / blocked).touch()
    model = SceneModel.from_artifact(stage_deformed)
    settings = RenderSettings(camera_ids=(0,), frame_stride=stage_scene.num_frames)
    with refused(InputError, str(tmp_path / blocked)):
        write_renders(stage_scene, model, tmp_path, settings, progress=False)
    assert not list(tmp_path.glob(".*"))


@pytest.mark.parametrize(("hold", "times"), [([], [0.0, 0.5, 1.0]), (["--path-frame", "5"], None)])
def test_a_path_renders_the_orbit_of_its_cameras_along_time_or_held(
    render, stage_scene_path, stage_deformed, tmp_path, hold, times
):
    out = tmp_path / "renders"
    args = ["--camera", "0", "--path", "3", "--no-video", *hold, "--out", str(out)]
    code, printed, _ = render(*args)
    assert code == 0 and f"  path: 3 frame(s) in {out / 'path'}\n" in printed
    assert sorted(p.name for p in out.iterdir()) == ["path"]
    scene = load_scene(stage_scene_path)
    (camera,) = [v.camera for v in scene.views_at(0, "all") if v.camera.camera_id == 0]
    orbit = path_cameras([camera], 3, scene.points.xyz.median(dim=0).values)
    renderer = ModelRenderer(SceneModel.from_artifact(stage_deformed))
    for view, time in enumerate(times or [frame_time(5, scene.num_frames)] * 3):
        written = cv2.imread(str(out / "path" / f"{view:06d}.png"))
        np.testing.assert_array_equal(written, _bgr(renderer.render([orbit[view]], time)[0]))


def test_a_path_through_the_train_cameras_is_a_video_by_default(
    render, stored_deform, stage_deformed, tmp_path
):
    store = stored_deform[0]
    out = tmp_path / "renders"
    args = ["--path", "5", "--path-frame", "0", "--out", str(out)]
    code, printed, _ = render(*args)
    assert code == 0 and f"video {out / 'path.mp4'}" in printed
    assert len(list((out / "path").glob("*.png"))) == 5
    frames = [cv2.imread(str(out / "path" / f"{view:06d}.png")) for view in range(5)]
    assert all(not np.array_equal(a, b) for a, b in itertools.pairwise(frames))
    video = cv2.VideoCapture(str(out / "path.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) == 5
    again = artifact_key("deform", 1, {"steps": 21}, "juggle", [])  # the same model again
    store.get_or_build("deform", again, lambda: stage_deformed, config={}, lineage=[])
    shorter = [*args[:1], "3", *args[2:], "--beside", again[:8]]
    assert render(*shorter)[0] == 0
    # a shorter path into the same folder replaces the frames; the model beside renders alike
    assert sorted(p.name for p in (out / "path").iterdir()) == [f"{v:06d}.png" for v in range(3)]
    view = cv2.imread(str(out / "path" / "000001.png"))
    np.testing.assert_array_equal(view[:, : view.shape[1] // 2], view[:, view.shape[1] // 2 :])


@pytest.mark.parametrize("time", [float("nan"), float("inf")])
def test_a_render_time_or_frame_rate_that_is_not_finite_is_one_line(
    stage_deformed, stage_scene_path, time
):
    camera = load_scene(stage_scene_path).train_views[0].camera
    renderer = ModelRenderer(SceneModel.from_artifact(stage_deformed))
    with refused(InputError, "render time", "[0, 1]"):
        renderer.render([camera], time)
    with refused(InputError, "fps", str(time)):
        RenderSettings(fps=time)
