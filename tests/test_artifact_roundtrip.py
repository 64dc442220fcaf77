"""Artifacts survive the store bit for bit, and meta that JSON would alter is refused."""

import pytest
import torch

from refusals import refused
from relaygs.errors import InputError
from relaygs.pipeline.artifact import Artifact, read_artifact_files, write_artifact_files


def _roundtrip(tmp_path, artifact):
    write_artifact_files(tmp_path, artifact)
    return read_artifact_files(tmp_path, artifact.stage)


def test_tensors_roundtrip_bitwise_with_dtypes_and_odd_layouts_and_meta_equal(tmp_path):
    base = torch.randn(4, 6, generator=torch.Generator().manual_seed(1))
    tensors = {
        "float": base,
        "transposed": base.t(),  # non-contiguous
        "view_of_float": base[1:3],  # shares storage with "float"
        "half": base.to(torch.float16),
        "bf16": base.to(torch.bfloat16),
        "bool": base > 0,
        "int64": torch.arange(-5, 5),
        "uint8": torch.arange(0, 250, 7, dtype=torch.uint8),
        "int32": torch.tensor([2**31 - 1, -(2**31)], dtype=torch.int32),
        "scalar": torch.tensor(3.5),
        "empty": torch.zeros(0, 3),
        "empty_too": torch.zeros(0, dtype=torch.int64),
        "specials": torch.tensor([-0.0, 1e-45, 3.4e38, -3.4e38]),  # signed zero, denormal, extremes
    }
    meta = {
        "metrics": {"psnr": 31.234567890123456, "loss": 1e-300, "neg_zero": -0.0},
        "counts": [1, 2, 3],
        "nested": {"flag": True, "none": None, "text": "ünï"},
        "big": 2**62,
    }
    loaded = _roundtrip(tmp_path, Artifact("decouple", tensors, meta))
    assert loaded.meta == meta
    assert str(loaded.meta["metrics"]["neg_zero"]) == "-0.0"
    (tmp_path / "none").mkdir()
    assert _roundtrip(tmp_path / "none", Artifact("relay")).tensors == {}  # no tensors is fine
    assert set(loaded.tensors) == set(tensors)
    for name, original in tensors.items():
        got = loaded.tensors[name]
        assert got.dtype == original.dtype, name
        assert got.shape == original.shape, name
        assert got.is_contiguous(), name
        assert torch.equal(
            got.view(-1).view(torch.uint8), original.contiguous().view(-1).view(torch.uint8)
        ), name


def _non_finite_means(bad: float) -> dict:
    means = torch.zeros(4, 3)
    means[2, 1] = bad
    return {"bg.means": means, "ok": torch.ones(2)}


@pytest.mark.parametrize(
    ("tensors", "meta", "named"),
    [
        ({}, {"size": (3, 4)}, ["size", "tuple"]),
        ({}, {"table": {1: "a"}}, ["key 1"]),
        ({}, {"t": torch.ones(1)}, ["t", "Tensor"]),
        ({}, {"s": {1, 2}}, ["s", "set"]),
        ({}, {"metrics": {"loss": float("nan")}}, ["metrics.loss", "nan"]),
        ({}, {"scores": [1.0, float("-inf")]}, ["scores[1]", "-inf"]),
        ({"x": [1, 2]}, {}, ["'x'", "list"]),
        (_non_finite_means(float("nan")), {}, ["'bg.means'", "1 non-finite"]),
        (_non_finite_means(float("inf")), {}, ["'bg.means'", "1 non-finite"]),
    ],
)
def test_what_json_or_safetensors_would_change_is_refused_and_nothing_written(
    tmp_path, tensors, meta, named
):
    with refused(InputError, *named):
        write_artifact_files(tmp_path, Artifact("deform", tensors, meta))
    assert list(tmp_path.iterdir()) == []
