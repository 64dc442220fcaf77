"""Pipeline files: shipped topologies, validation errors, and running a DAG of fake stages."""

import itertools
from types import SimpleNamespace

import pytest
import torch

from refusals import refused
from relaygs import paths
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact
from relaygs.pipeline.dag import run_pipeline
from relaygs.pipeline.spec import available_pipelines, load_pipeline
from relaygs.pipeline.store import ArtifactStore

SHIPPED = {
    "relaygs": ["decouple", "relay", "deform"],
    "4dgs": ["warmup", "deform"],
    "no_stage2": ["decouple", "replicate", "deform"],
    "no_copies": ["decouple", "deform"],
    "decouple": ["decouple"],
}
KNOWN_STAGES = {"decouple", "relay", "deform", "warmup", "replicate"}


@pytest.mark.parametrize(("name", "chain"), SHIPPED.items())
def test_shipped_pipelines_are_the_documented_chains_of_upstreams_their_stages_read(name, chain):
    from relaygs.stages import SPECS

    upstream = {spec.name: spec.upstream for spec in SPECS.values()}
    pipeline = load_pipeline(name, known_stages=SPECS, accepted_upstream=upstream)
    order = pipeline.topological_order()
    assert [node.stage for node in order] == chain
    for parent, child in itertools.pairwise(order):
        assert child.upstream == (parent.name,)
    assert pipeline.output_node.stage == chain[-1]
    assert pipeline.path.is_absolute() and name in available_pipelines()


def _write(tmp_path, text, name="p.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_topological_order_puts_upstreams_first_whatever_the_file_order(tmp_path):
    path = _write(
        tmp_path,
        "nodes:\n"
        "  c: {stage: deform, upstream: [b, a]}\n"
        "  b: {stage: relay, upstream: [a]}\n"
        "  a: {stage: decouple}\n",
    )
    assert [node.name for node in load_pipeline(path).topological_order()] == ["a", "b", "c"]


@pytest.mark.parametrize(
    ("text", "named"),
    [
        ("nodes:\n  a: {stage: decouple, upstream: [zz]}\n", ["'zz'"]),
        (
            "nodes:\n  a: {stage: decouple, upstream: [b]}\n  b: {stage: relay, upstream: [a]}\n"
            "  c: {stage: deform, upstream: [b]}\n",
            ["cycle", "a -> b"],
        ),
        ("nodes:\n  a: {stage: decouple, upstream: [a]}\n", ["cycle", "a -> a"]),
        ("nodes:\n  a: {stage: teleport}\n", ["'teleport'"]),
        ("nodes:\n  a: {stage: decouple, inputs: []}\n", ["['inputs']"]),
        ("nodes:\n  a: {upstream: []}\n", ["'a'", "'stage'"]),
        ("nodes:\n  a: {stage: relay, upstream: b}\n", ["'a'", "'upstream'"]),
        ("nodes:\n  a: {stage: decouple}\n  b: {stage: relay, upstream: [a, a]}\n", ["['a', 'a']"]),
        ("nodes: {}\n", ["'nodes'"]),
        ("steps: 3\nnodes:\n  a: {stage: decouple}\n", ["['steps']"]),
        ("description: [x]\nnodes:\n  a: {stage: decouple}\n", ["'description'"]),
        ("nodes:\n  a.b: {stage: decouple}\n", ["'a.b'"]),
        ("nodes:\n  a: decouple\n", ["'a'", "'stage'"]),
        ("- a\n- b\n", ["'nodes'"]),
        ("nodes: [unclosed\n", ["line 2"]),
        # before: "(while parsing a flow mapping)", with no line
        ("nodes:\n  a: {stage: decouple\n  b: {stage: relay}\n", ["line 3, column 4"]),
        ("nodes:\n  a: {stage: decouple}\n  b: {stage: relay}\n", ["output node"]),
    ],
)
def test_invalid_pipelines_fail_in_one_line_naming_the_file(tmp_path, text, named):
    path = _write(tmp_path, text)
    with refused(InputError, str(path), *named):
        load_pipeline(path, known_stages=KNOWN_STAGES)


ACCEPTS = {"decouple": (), "relay": ("decouple",), "deform": ("relay", "warmup")}


@pytest.mark.parametrize(
    ("text", "named"),
    [
        (
            "nodes:\n  a: {stage: warmup}\n  b: {stage: relay, upstream: [a]}\n",
            ["'b'", "'relay'", "decouple", "'a'", "'warmup'"],
        ),
        ("nodes:\n  a: {stage: decouple}\n  b: {stage: decouple, upstream: [a]}\n", ["'b'", "'a'"]),
        ("nodes:\n  a: {stage: deform}\n", ["'a'", "relay or warmup", "none"]),
        (
            "nodes:\n  a: {stage: warmup}\n  b: {stage: decouple}\n"
            "  c: {stage: deform, upstream: [a, b]}\n",
            ["'c'", "'a' of type 'warmup'", "'b' of type 'decouple'"],
        ),
    ],
)
def test_an_upstream_a_stage_type_does_not_read_fails_before_any_stage_runs(tmp_path, text, named):
    # before: found only when the stage ran, after its upstreams had trained
    path = _write(tmp_path, text)
    with refused(InputError, str(path), *named):
        load_pipeline(path, known_stages=KNOWN_STAGES, accepted_upstream=ACCEPTS)
    load_pipeline(path, known_stages=KNOWN_STAGES)  # not checked without `accepted_upstream`


def test_unknown_pipeline_name_lists_the_available_ones():
    with refused(InputError, "'nope'", "pipeline/nope.yaml", "relaygs"):
        load_pipeline("nope")
    with refused(InputError, "/no/such/pipeline.yaml"):
        load_pipeline("/no/such/pipeline.yaml")


class FakeStages:
    """Stage functions that return arange tensors shifted by their inputs, and count calls and
    record the config of each (`seen`)."""

    def __init__(self):
        self.calls, self.seen = {}, []

    def fn(self, stage):
        def run(scene, upstream, cfg):
            self.calls[stage] = self.calls.get(stage, 0) + 1
            self.seen.append((stage, cfg))
            base = sum(float(a.tensors["x"].sum()) for a in upstream.values())
            x = torch.arange(4.0) * cfg["scale"] + base
            meta = {"upstream": sorted(upstream), "scene": scene.fingerprint}
            return Artifact(stage, {"x": x}, meta)

        return run

    def table(self):
        return {stage: self.fn(stage) for stage in KNOWN_STAGES}


BASE = {"decouple": {"scale": 1.0}, "relay": {"scale": 2.0, "k": 4}, "deform": {"scale": 3.0}}


def _run(store, stages, cfgs=BASE, pipeline="relaygs", scene="scene-a", **options):
    """Run a shipped pipeline on FakeStages (or a table of stage functions) with `cfgs`."""
    table = stages if isinstance(stages, dict) else stages.table()
    scene = SimpleNamespace(fingerprint=scene)
    return run_pipeline(
        load_pipeline(pipeline), table, scene, lambda n: cfgs[n.stage], store, **options
    )


def test_run_builds_each_stage_once_records_its_lineage_then_hits_the_cache(tmp_path):
    store, stages = ArtifactStore(tmp_path), FakeStages()
    extra = {"test_cameras": [1, 5], "node": "not this"}
    first = _run(store, stages, BASE, provenance=extra)
    second = _run(store, stages, BASE)
    assert stages.calls == {"decouple": 1, "relay": 1, "deform": 1}
    assert [r.cache_hit for r in first.reports] == [False, False, False]
    assert [r.cache_hit for r in second.reports] == [True, True, True]
    assert [r.key for r in first.reports] == [r.key for r in second.reports]
    assert torch.equal(first.output.tensors["x"], second.output.tensors["x"])
    assert second.output.meta == {"upstream": ["relay"], "scene": "scene-a"}
    assert second.train_seconds_computed == 0.0
    assert second.train_seconds_total == pytest.approx(first.train_seconds_total)
    decouple, relay, deform = first.reports
    lineage = store.manifest("deform", deform.key).lineage
    assert [(e.node, e.stage, e.key) for e in lineage] == [("relay", "relay", relay.key)]
    assert deform.lineage_seconds == pytest.approx(
        decouple.wall_seconds + relay.wall_seconds + deform.wall_seconds
    )
    assert first.train_seconds_total == pytest.approx(deform.lineage_seconds)
    for report in first.reports:  # the given provenance beside the runner's own entries
        provenance = store.manifest(report.stage, report.key).provenance
        assert provenance["test_cameras"] == [1, 5]
        assert provenance["node"] == report.node and provenance["scene"] == "scene-a"


def test_changing_a_downstream_config_or_schema_version_rebuilds_only_downstream(tmp_path):
    store, stages = ArtifactStore(tmp_path), FakeStages()
    first = _run(store, stages, BASE)
    changed = _run(store, stages, {**BASE, "relay": {"scale": 2.0, "k": 8}})
    assert stages.calls == {"decouple": 1, "relay": 2, "deform": 2}
    assert [r.cache_hit for r in changed.reports] == [True, False, False]
    assert changed.reports[2].key != first.reports[2].key  # new upstream key, same own config
    no_copies = _run(store, stages, BASE, pipeline="no_copies")  # shares decouple's artifact
    assert no_copies.reports[0].cache_hit and no_copies.reports[0].key == first.reports[0].key
    assert not no_copies.reports[1].cache_hit
    assert no_copies.output.meta["upstream"] == ["decouple"]
    reports = []
    _run(store, stages, schema_versions={"relay": 2}, on_node_done=reports.append)
    assert [r.cache_hit for r in reports] == [True, False, False]


def test_paths_and_logging_do_not_rebuild_but_the_stage_still_sees_them(tmp_path):
    store, stages = ArtifactStore(tmp_path), FakeStages()
    _run(store, stages, BASE)
    noisy = {**BASE, "decouple": {"scale": 1.0, "paths": {"out": "/x"}, "logging": {"every": 1}}}
    run = _run(store, stages, noisy)
    assert all(r.cache_hit for r in run.reports) and len(stages.seen) == 3
    other_scene = _run(store, stages, noisy, scene="scene-b")
    assert not any(r.cache_hit for r in other_scene.reports)
    assert stages.seen[3] == ("decouple", noisy["decouple"])


def test_missing_stage_functions_fail_before_any_work(tmp_path):
    store, stages = ArtifactStore(tmp_path), FakeStages()
    table = stages.table()
    del table["deform"]
    with refused(InputError, "'deform'"):
        _run(store, table)
    assert stages.calls == {} and store.list() == []


def test_the_config_folder_prefers_the_repo_then_the_packaged_copy(tmp_path, monkeypatch):
    repo, packaged = tmp_path / "repo", tmp_path / "packaged"
    monkeypatch.setattr(paths, "REPO_ROOT", repo)
    monkeypatch.setattr(paths, "PACKAGE_DIR", repo / "src" / "relaygs")  # a relaygs checkout
    monkeypatch.setattr(paths, "PACKAGED_DATA_DIR", packaged)
    repo.mkdir()
    (repo / "pyproject.toml").write_text('[project]\nname = "relaygs"\n')
    (repo / "conf").mkdir()
    with refused(InputError, "conf"):
        paths.config_dir()  # a conf/ without config.yaml does not count
    (repo / "conf" / "config.yaml").write_text("seed: 0\n")
    assert paths.config_dir() == repo / "conf"


def test_a_canonical_form_is_what_is_keyed_and_what_the_stage_runs_with(tmp_path):
    stages = FakeStages()

    def cap_k(stage, cfg, scene):
        return {**cfg, "k": min(cfg["k"], 4)} if stage == "relay" else cfg

    wide = {**BASE, "relay": {"scale": 2.0, "k": 16}}
    run = _run(ArtifactStore(tmp_path / "canonical"), stages, wide, canonical=cap_k)
    assert stages.seen[1] == ("relay", BASE["relay"])  # built (no cache) with k capped to 4
    plain = _run(ArtifactStore(tmp_path / "plain"), FakeStages(), BASE)
    assert [r.key for r in run.reports] == [r.key for r in plain.reports]


@pytest.mark.parametrize(
    "returned", [None, {"x": torch.zeros(1)}, SimpleNamespace(stage="decouple")]
)
def test_a_stage_that_returns_no_artifact_is_one_line_naming_it(tmp_path, returned):
    # before: AttributeError ('NoneType' object has no attribute 'stage', ... 'to_cpu_contiguous')
    table = {**FakeStages().table(), "decouple": lambda scene, upstream, cfg: returned}
    with refused(InputError, "'decouple'", "Artifact"):
        _run(ArtifactStore(tmp_path), table)
