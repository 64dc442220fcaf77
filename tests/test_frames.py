"""`python -m relaygs.frames`: one video per camera → the multi-view layout's frame folders."""

import json
import shlex
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser

from refusals import refused
from relaygs.commands import frames as frames_command
from relaygs.data import load_scene
from relaygs.data import video_frames as video_frames_module
from relaygs.data.export import export_multiview
from relaygs.data.synthetic import generate
from relaygs.data.video_frames import decoded_frames
from relaygs.errors import InputError
from relaygs.shell import python_command


def _video(path: Path, images: list[np.ndarray], fps: float = 30.0) -> Path:
    height, width = images[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    for image in images:
        writer.write(image)
    writer.release()
    return path


def _grey_video(path: Path, count: int) -> Path:
    """A 32×18 video whose frame i is flat grey 20·i (told apart after lossy coding)."""
    return _video(path, [np.full((18, 32, 3), 20 * i, np.uint8) for i in range(count)])


def _main(capsys, *argv):
    code = frames_command.main([str(arg) for arg in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def videos(tmp_path):
    folder = tmp_path / "videos"
    folder.mkdir()
    for name, count in (("side_2.mp4", 9), ("side_10.mp4", 8), ("side_1.MP4", 10)):
        _grey_video(folder / name, count)
    (folder / "notes.txt").write_text("not a video")
    (folder / "clips.mp4").mkdir()  # a folder, whatever its name
    _grey_video(folder / ".hidden.mp4", 9)  # hidden files are no cameras,
    (folder / "._side_2.mp4").write_bytes(b"\0" * 64)  # nor macOS's resource forks
    return folder


def test_frames_are_written_in_natural_order_cut_to_the_shortest_video(videos, tmp_path, capsys):
    out = tmp_path / "scene"
    code, printed, err = _main(capsys, videos, out, "--start", 1, "--stride", 2, "--format", "png")
    assert code == 0, err
    sources = {"cam00": "side_1.MP4", "cam01": "side_2.mp4", "cam02": "side_10.mp4"}
    # source frames 1, 3, 5, 7 exist in every video (the shortest has 8), 9 only in side_1
    for camera, source in sources.items():
        written = sorted(path.name for path in (out / camera).iterdir())
        assert written == [f"frame_{n:05d}.png" for n in range(4)]
        expected = list(decoded_frames(cv2.VideoCapture(str(videos / source))))[1::2][:4]
        for number, image in enumerate(expected):
            assert np.array_equal(cv2.imread(str(out / camera / f"frame_{number:05d}.png")), image)
    listing = json.loads((out / "frames.json").read_text())
    assert listing["sources"] == {name: str(videos / video) for name, video in sources.items()}
    assert (listing["frames"], listing["start"], listing["stride"], listing["fps"]) == (4, 1, 2, 15)
    first = (out / "colmap_images.txt").read_text().split()
    assert first == [f"{camera}/frame_00000.png" for camera in sources]
    assert printed.startswith(f"wrote 4 frame(s) at 15 fps of 3 camera(s) into {out}")
    (note,) = [line for line in printed.splitlines() if line.startswith("note: every camera")]
    assert "4 frame(s)" in note and "cam02" in note and "cam00" in note
    assert f"then train: {python_command()} -m relaygs.run scene.path={out}\n" in printed + "\n"


@pytest.mark.parametrize(
    ("lengths", "options", "frames"),
    [
        ((9, 8, 10), ["--frames", 3], 3),  # the count asked for, not a short video
        ((5, 5, 5), [], 5),
        ((10, 9), ["--stride", 2], 5),  # frames 0, 2, 4, 6, 8 of both: five each
    ],
)
def test_a_count_every_video_gives_gets_no_note(tmp_path, capsys, lengths, options, frames):
    folder = tmp_path / "videos"
    folder.mkdir()
    for camera, count in enumerate(lengths):
        _grey_video(folder / f"{camera}.mp4", count)
    code, printed, _ = _main(capsys, folder, tmp_path / "scene", *options)
    assert code == 0 and printed.startswith(f"wrote {frames} frame(s)") and "note:" not in printed
    written = sorted(path.name for path in (tmp_path / "scene" / "cam00").iterdir())
    assert written == [f"frame_{n:05d}.jpg" for n in range(frames)]


def test_the_written_folder_loads_as_a_multiview_scene_once_posed(tmp_path, capsys):
    synthetic = load_scene(generate("juggle", tmp_path / "synth", frames=3, width=32, height=18))
    exported = export_multiview(synthetic, tmp_path / "exported")
    videos = tmp_path / "videos"
    videos.mkdir()
    for camera in sorted(exported.glob("cam*")):
        frames = [cv2.imread(str(path)) for path in sorted(camera.iterdir())]
        _video(videos / f"{camera.name}.mp4", frames)
    out = tmp_path / "from_videos"
    assert _main(capsys, videos, out, "--format", "png")[0] == 0
    shutil.copytree(exported / "sparse", out / "sparse")  # the pose COLMAP would find
    scene = load_scene(out)
    assert scene.num_frames == 3
    assert len(scene.train_views) + len(scene.test_views) == 3 * 31
    view = scene.test_views[0]
    truth = synthetic.image(next(v for v in synthetic.test_views if v.frame == view.frame))
    assert float((scene.image(view) - truth).abs().mean()) < 0.05  # the video codec's loss only


def _only_one_video(videos: Path, out: Path) -> None:
    for video in videos.glob("side_*"):
        if video.name != "side_2.mp4":
            video.unlink()


@pytest.mark.parametrize(
    ("prepare", "args", "named"),
    [
        (lambda videos, out: shutil.rmtree(videos) or videos.mkdir(), [], ["at least 2, found 0"]),
        (_only_one_video, [], ["expected a video per camera", "found 1"]),
        (lambda videos, out: out.mkdir() or (out / "keep.txt").write_text("x"), [], ["not empty"]),
        (lambda videos, out: out.write_text("x"), [], ["scene is a file", "new or empty folder"]),
        # the shortest video is decoded first
        (lambda videos, out: None, ["--start", "50"], ["side_10.mp4", "8", "50"]),
    ],
    ids=["no-videos", "one-video", "out-not-empty", "out-is-a-file", "start-past-the-end"],
)
def test_bad_input_is_one_line_and_leaves_nothing_behind(
    videos, tmp_path, capsys, prepare, args, named
):
    out = tmp_path / "scene"
    prepare(videos, out)
    before = sorted(tmp_path.rglob("*"))
    code, printed, err = _main(capsys, videos, out, *args)
    assert code == 1 and printed == ""
    last = err.rsplit("\r", 1)[-1]
    assert last.startswith("error: ") and last.count("\n") == 1
    assert all(name in last for name in named), last
    assert sorted(tmp_path.rglob("*")) == before


def test_an_interrupted_extraction_leaves_no_partial_scene(videos, tmp_path, monkeypatch):
    written = []

    def write_then_stop(path, image):
        written.append(path)
        if len(written) == 5:
            raise KeyboardInterrupt

    monkeypatch.setattr(video_frames_module, "_write_image", write_then_stop)
    with pytest.raises(KeyboardInterrupt):
        frames_command.main([str(videos), str(tmp_path / "scene")])
    assert sorted(path.name for path in tmp_path.iterdir()) == ["videos"]


def test_a_killed_runs_unfinished_staging_folder_is_removed_and_noted(videos, tmp_path, capsys):
    killed = tmp_path / ".scene.partial-999999998"  # no such process: killed
    (killed / "cam00").mkdir(parents=True)
    renamed_failed = tmp_path / ".scene.partial-999999999"  # a dead pid, but its frames finished
    renamed_failed.mkdir()
    (renamed_failed / "frames.json").write_text("{}")
    running = tmp_path / ".scene.partial-1"  # pid 1 is always there
    other = tmp_path / ".scene.partial-old"
    for folder in (running, other):
        folder.mkdir()
    code, out, _ = _main(capsys, videos, tmp_path / "scene")
    assert code == 0 and not killed.exists()
    assert renamed_failed.is_dir() and running.is_dir() and other.is_dir()
    assert f"note: removed {killed}, left unfinished by a run that was killed" in out


@pytest.mark.parametrize("argv", [["--stride", "0"], ["--start", "-1"], ["--format", "gif"]])
def test_bad_options_are_usage_errors(videos, tmp_path, capsys, argv):
    with pytest.raises(SystemExit) as stopped:
        frames_command.main([str(videos), str(tmp_path / "scene"), *argv])
    err = capsys.readouterr().err
    assert stopped.value.code == 2 and err.startswith("error: ") and err.count("\n") == 1


@pytest.mark.parametrize("name", ["scene", "my scene", "scène", 'odd"name', 'a\\"b', "ends\\"])
def test_the_printed_run_override_reads_back_as_the_folder(tmp_path, name):
    folder = tmp_path / name
    (word,) = shlex.split(frames_command.path_override("scene.path", folder))
    override = OverridesParser.create().parse_override(word)
    assert override.key_or_group == "scene.path" and override.value() == str(folder)


def test_an_output_folder_given_as_a_link_fills_its_target(videos, tmp_path, capsys):
    target = tmp_path / "target"
    target.mkdir()
    (tmp_path / "link").symlink_to(target)
    assert _main(capsys, videos, tmp_path / "link")[0] == 0
    assert (tmp_path / "link").is_symlink() and (target / "cam00" / "frame_00000.jpg").is_file()


def test_videos_at_different_rates_are_noted(tmp_path, capsys):
    folder = tmp_path / "videos"
    folder.mkdir()
    for name, fps in (("a.mp4", 30.0), ("b.mp4", 25.0)):
        _video(folder / name, [np.full((18, 32, 3), 40 * i, np.uint8) for i in range(3)], fps)
    code, printed, _ = _main(capsys, folder, tmp_path / "scene")
    assert code == 0 and " fps " not in printed.splitlines()[0]
    (note,) = [line for line in printed.splitlines() if line.startswith("note: ")]
    assert "cam00 30" in note and "cam01 25" in note
    assert json.loads((tmp_path / "scene" / "frames.json").read_text())["fps"] is None


def test_a_video_cut_short_is_named(tmp_path, capsys):
    folder = tmp_path / "videos"
    folder.mkdir()
    noise = np.random.default_rng(0).integers(0, 256, (40, 18, 32, 3), dtype=np.uint8)
    for name in ("a.avi", "b.avi"):
        path = folder / name
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (32, 18))
        for image in noise:  # frames that do not compress away, so a cut falls among them
            writer.write(image)
        writer.release()
    data = (folder / "b.avi").read_bytes()
    (folder / "b.avi").write_bytes(data[: len(data) // 2])  # its header still states 40
    code, printed, _ = _main(capsys, folder, tmp_path / "scene")
    assert code == 0
    frames = int(printed.split()[1])
    assert 0 < frames < 40
    assert f"note: every camera keeps {frames} frame(s), all that cam01 gave; cam00 had more\n" in (
        printed
    )
    assert f"note: cam01's b.avi decoded {frames} of the 40 frames it states" in printed


def test_a_scene_folder_or_a_videos_folder_given_to_the_wrong_command_says_which_to_use(
    videos, tmp_path, capsys
):
    scene = tmp_path / "scene"
    assert _main(capsys, videos, scene)[0] == 0
    code, _, err = _main(capsys, scene, tmp_path / "again")
    run = f"{python_command()} -m relaygs.run scene.path={scene}"
    assert code == 1 and f"its camXX folders make it a scene: {run}" in err
    with pytest.raises(InputError) as caught:
        load_scene(videos)
    frames = f"{python_command()} -m relaygs.frames {videos} SCENE_DIR"
    assert str(caught.value).endswith(f"for one video per camera, run {frames}")


def test_a_video_that_does_not_open_is_refused_before_any_is_decoded(videos, tmp_path, monkeypatch):
    (videos / "side_99.mp4").write_bytes(b"\0" * 64)  # sorts last
    decoded = []
    monkeypatch.setattr(video_frames_module, "_write_camera", lambda *args: decoded.append(args))
    with refused(InputError, "side_99.mp4"):
        video_frames_module.extract_frames(
            video_frames_module.camera_videos(videos), tmp_path / "scene", progress=False
        )
    assert decoded == [] and sorted(path.name for path in tmp_path.iterdir()) == ["videos"]


def test_a_failed_final_move_keeps_the_frames_and_names_where(videos, tmp_path, monkeypatch):
    def refuse(source, target):
        raise OSError(18, "Invalid cross-device link")

    monkeypatch.setattr(video_frames_module.os, "replace", refuse)
    with pytest.raises(InputError) as caught:
        video_frames_module.extract_frames(
            video_frames_module.camera_videos(videos), tmp_path / "scene", progress=False
        )
    (staging,) = tmp_path.glob(".scene.partial-*")
    assert str(staging) in str(caught.value) and "Invalid cross-device link" in str(caught.value)
    assert (staging / "cam02" / "frame_00000.jpg").is_file() and not (tmp_path / "scene").exists()
