"""Scene resolution: synthetic scenes are generated once into a parameter-hashed cache folder
(parallel jobs included); capture folders are checked before any work."""

import dataclasses
import functools
import re
import threading
import time
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from fake_stages import compose_config
from refusals import refused
from relaygs.app import scenes
from relaygs.app.scenes import prepare_scene, scene_provenance, scene_spec, synthetic_folder
from relaygs.data import load_scene
from relaygs.data.effects import SENSOR_NOISE
from relaygs.data.synthetic import PRESETS
from relaygs.data.synthetic.presets import build_static
from relaygs.data.synthetic.rig import ring_rig
from relaygs.errors import InputError

TINY = {
    "name": "juggle",
    "preset": "juggle",
    "path": None,
    "frames": 2,
    "width": 16,
    "height": 9,
    "seed": 0,
    "effects": None,
    "loader": {},
}


def test_cache_folder_depends_on_every_generation_parameter(tmp_path):
    base = synthetic_folder(scene_spec(TINY), tmp_path)
    assert base.parent == tmp_path and base.name.startswith("juggle-")
    assert synthetic_folder(scene_spec(dict(TINY)), tmp_path) == base
    for change in ({"frames": 3}, {"width": 17}, {"seed": 1}, {"effects": ["sensor_noise"]}):
        assert synthetic_folder(scene_spec({**TINY, **change}), tmp_path) != base
    renamed = synthetic_folder(scene_spec({**TINY, "name": "label"}), tmp_path)
    assert renamed == base  # the label is not a generation parameter
    # effects `none` is no effects, as in synth
    no_effects = synthetic_folder(scene_spec({**TINY, "effects": []}), tmp_path)
    for none in ("none", ["none"]):
        assert scene_spec({**TINY, "effects": none}).effects == ()
        assert synthetic_folder(scene_spec({**TINY, "effects": none}), tmp_path) == no_effects


@pytest.mark.parametrize(
    "edit",
    [
        {"test_cameras": (0, 10)},
        {"default_effects": frozenset({SENSOR_NOISE})},
        {"supported_effects": PRESETS["juggle"].supported_effects - {SENSOR_NOISE}},
        {"rig": ring_rig},
        {"build": build_static},
        {"rig": functools.partial(ring_rig)},
        {"revision": 2},  # the builder changed what it draws
    ],
)
def test_cache_folder_depends_on_the_preset_definition(tmp_path, monkeypatch, edit):
    base = synthetic_folder(scene_spec(TINY), tmp_path)
    monkeypatch.setitem(PRESETS, "juggle", dataclasses.replace(PRESETS["juggle"]))
    assert synthetic_folder(scene_spec(TINY), tmp_path) == base  # an equal copy: same folder
    reworded = dataclasses.replace(PRESETS["juggle"], description="reworded")
    monkeypatch.setitem(PRESETS, "juggle", reworded)
    assert synthetic_folder(scene_spec(TINY), tmp_path) == base  # no generation parameter
    monkeypatch.setitem(PRESETS, "juggle", dataclasses.replace(PRESETS["juggle"], **edit))
    assert synthetic_folder(scene_spec(TINY), tmp_path) != base


def test_only_a_raised_revision_enters_a_preset_definition():
    # so the presets never revised keep the cache folders (and scene keys) they had
    assert "revision" not in PRESETS["juggle"].definition()
    assert PRESETS["court"].definition()["revision"] == 2


def test_the_docs_quote_the_cache_folder_of_the_default_juggle_scene(tmp_path):
    # the same in every process (no object addresses in the hash), as the docs show it
    default = OmegaConf.to_container(compose_config([], tmp_path).scene, resolve=True)
    folder = synthetic_folder(scene_spec(default), Path("outputs/scenes")).as_posix()
    root = Path(__file__).resolve().parents[1]
    pages = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
    quoted = {
        match
        for page in pages
        for match in re.findall(r"outputs/scenes/juggle-\w+", page.read_text(encoding="utf-8"))
    }
    assert quoted == {folder}


@pytest.mark.parametrize(
    ("edit", "named"),
    [
        # before: refused only by the cache key, as "scene.definition.default_effects is a set"
        ({"default_effects": set()}, [".default_effects", "set"]),
        # before: taken, its scene.json labelled with the other name
        ({"name": "court"}, [".name", "'court'", "'juggle'"]),
        # before: generated, then refused by the loader as a test_meta.json without frames
        ({"test_cameras": ()}, [".test_cameras"]),
        # before: `run` took the edited preset (its cached scene, or a failure after other work)
        ({"test_cameras": (0, 99)}, [".test_cameras", "[0, 99]"]),
        ({"build": lambda times, effects, seed: []}, [".build"]),  # no stable name to hash
    ],
)
def test_a_broken_preset_is_refused_before_generation(tmp_path, monkeypatch, edit, named):
    monkeypatch.setitem(PRESETS, "juggle", dataclasses.replace(PRESETS["juggle"], **edit))
    with refused(InputError, "PRESETS['juggle']", *named):
        synthetic_folder(scene_spec(TINY), tmp_path)
    assert not any(tmp_path.iterdir())


def test_a_synthetic_scene_is_generated_once_and_then_loaded(tmp_path, monkeypatch):
    calls = []
    real_generate = scenes.generate

    def counting_generate(*args, **kwargs):
        calls.append(args)
        time.sleep(0.2)  # give the other thread time to reach the lock
        return real_generate(*args, **kwargs)

    monkeypatch.setattr(scenes, "generate", counting_generate)
    spec = scene_spec(TINY)
    loaded = []
    threads = [
        threading.Thread(target=lambda: loaded.append(prepare_scene(spec, tmp_path)))
        for _ in range(2)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(calls) == 1
    assert len(loaded) == 2 and loaded[0].fingerprint == loaded[1].fingerprint
    assert loaded[0].num_frames == 2
    prepare_scene(spec, tmp_path)
    assert len(calls) == 1


def test_a_capture_path_is_loaded_in_place_and_its_errors_name_the_runs_option(
    tiny_synth_scene, tmp_path
):
    spec = scene_spec({**TINY, "path": str(tiny_synth_scene), "name": None})
    assert not spec.is_synthetic and spec.name == tiny_synth_scene.name
    assert prepare_scene(spec, tmp_path / "unused").root == tiny_synth_scene
    assert not (tmp_path / "unused").exists()
    spec = scene_spec({**TINY, "path": str(tiny_synth_scene), "loader": {"test_cameras": [99]}})
    with refused(InputError, "scene.loader.test_cameras", "[99]"):
        prepare_scene(spec, tmp_path)
    with refused(InputError, "test_cameras", "[99]"):
        load_scene(tiny_synth_scene, test_cameras=[99])


def test_the_loading_a_run_records_loads_its_scene_again_as_the_run_did(tiny_synth_scene, tmp_path):
    loader = {"downscale": 2, "max_points": 50, "test_cameras": [3, 1], "cache_mb": 8}
    section = {**TINY, "path": str(tiny_synth_scene), "effects": ["sensor_noise"]}
    capture = scene_spec({**section, "loader": loader})
    recorded = scene_provenance(capture)
    assert recorded == {
        "downscale": 2,
        "max_points": 50,
        "test_cameras": [1, 3],
        "effects": ["sensor_noise"],
    }
    as_run = prepare_scene(capture, tmp_path).fingerprint
    assert load_scene(tiny_synth_scene, **recorded).fingerprint == as_run
    assert load_scene(tiny_synth_scene, downscale=2, test_cameras=[1, 3]).fingerprint != as_run
    assert scene_provenance(scene_spec({**section, "loader": {}})) == {"effects": ["sensor_noise"]}
    # a generated scene's effects are in its files: loading it does not pass them again
    assert scene_provenance(scene_spec({**TINY, "effects": ["sensor_noise"]})) == {}


def test_held_out_cameras_within_the_rig_are_accepted_before_generation():
    # the highest id of juggle's 31-camera dome, and all but one camera, are valid
    for held_out in ([30], list(range(30))):
        spec = scene_spec({**TINY, "loader": {"test_cameras": held_out}})
        assert spec.loader["test_cameras"] == held_out


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"colour": "red"}, ["scene", "'colour'"]),
        ({"effects": ["none", "nonrigid"]}, ["scene.effects", "'none'"]),
        ({"path": "{tmp}/missing"}, ["scene.path", "{tmp}/missing"]),
        ({"path": "{tmp}/frames.txt"}, ["scene.path", "frames.txt"]),
        ({"path": "{tmp}"}, ["{tmp}", "train_meta.json", "camXX"]),  # no known layout
    ],
)
def test_a_bad_scene_section_is_refused_naming_the_field(tmp_path, changes, named):
    (tmp_path / "frames.txt").write_text("not a scene")
    changes = {k: v.format(tmp=tmp_path) if k == "path" else v for k, v in changes.items()}
    with refused(InputError, *(name.format(tmp=tmp_path) for name in named)):
        scene_spec({**TINY, **changes})


@pytest.mark.parametrize(
    ("overrides", "label"),
    [
        ([], "juggle"),
        (["scene=court"], "court"),
        (["scene.path={capture}"], "{capture_name}"),
        (["scene.path={capture}", "scene.name=basketball"], "basketball"),
    ],
)
def test_results_label_the_scene_by_name_else_capture_folder_else_preset(
    tiny_synth_copy, tmp_path, overrides, label
):
    capture = tiny_synth_copy.rename(tmp_path / "studio_take2")
    fill = {"capture": str(capture), "capture_name": capture.name}
    cfg = compose_config([item.format(**fill) for item in overrides], tmp_path)
    section = OmegaConf.to_container(cfg.scene, resolve=True)
    assert scene_spec(section).name == label.format(**fill)
