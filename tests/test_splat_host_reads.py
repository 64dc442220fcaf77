"""The torch compositor reads nothing back from the device per tile group: on a GPU every such
read (`int(tensor)`, `.item()`, `.tolist()`, `bool(tensor)`) waits for all queued work."""

from __future__ import annotations

import pytest
import torch

from relaygs.splat import composite, rasterization
from splat_scenes import random_scene, with_grad

HOST_READS = ("__int__", "__index__", "__bool__", "__float__", "item", "tolist")


@pytest.fixture
def host_reads(monkeypatch):
    """The names of the tensor-to-host reads made, in order, from Python."""
    made: list[str] = []
    for name in HOST_READS:
        original = getattr(torch.Tensor, name)

        def counted(self, *args, _original=original, _name=name, **kwargs):
            made.append(_name)
            return _original(self, *args, **kwargs)

        monkeypatch.setattr(torch.Tensor, name, counted)
    return made


@pytest.fixture
def groups_composited(monkeypatch):
    """How many tile groups the compositor gathered rows for."""
    gathered: list[int] = []
    original = composite._rows

    def counting(*args):
        gathered.append(1)
        return original(*args)

    monkeypatch.setattr(composite, "_rows", counting)
    return gathered


def test_host_reads_do_not_grow_with_the_tile_groups(host_reads, groups_composited):
    reads = []
    for width, height in ((16, 16), (16, 16), (160, 120)):
        scene = with_grad(random_scene(3000, seed=0, num_cameras=4, width=width, height=height))
        host_reads.clear()
        groups_composited.clear()
        colors, alphas, _ = rasterization(**scene, backend="torch")
        forward = list(host_reads)
        host_reads.clear()
        (colors.sum() + alphas.sum()).backward()
        reads.append((forward, list(host_reads), len(groups_composited)))
    (_, _, few), (small_forward, small_backward, _), (forward, backward, many) = reads
    assert many > 4 * few  # forward and backward each gather every group
    # one read checks the intrinsics, two size the binning's pairs and groups
    assert forward == small_forward and len(forward) <= 3
    assert small_backward == backward == []
