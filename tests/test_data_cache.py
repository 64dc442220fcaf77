"""The image cache's LRU eviction and the voxel downsampling of initial point clouds."""

from __future__ import annotations

import numpy as np
import torch

from relaygs.data.cache import TensorCache
from relaygs.data.points import voxel_downsample


def test_cache_evicts_least_recently_used_first():
    cache = TensorCache(budget_mb=3 * 1024 / 2**20)  # three 256-float tensors
    loads = []

    def loader(value: float):
        def load() -> torch.Tensor:
            loads.append(value)
            return torch.full((256,), float(value))

        return load

    for key in "abc":
        cache.get(key, loader(ord(key)))
    cache.get("a", loader(0.0))
    cache.get("d", loader(ord("d")))
    assert len(cache) == 3 and cache.used_bytes == 3 * 1024
    cache.get("a", loader(0.0))
    cache.get("b", loader(1.0))
    assert loads == [ord("a"), ord("b"), ord("c"), ord("d"), 1.0]


def test_voxel_downsample_meets_the_budget_and_averages():
    rng = np.random.default_rng(0)
    xyz = rng.random((5000, 3))
    rgb = rng.random((5000, 3))
    is_fg = xyz[:, 0] > 0.5
    out_xyz, out_rgb, out_fg = voxel_downsample(xyz, rgb, is_fg, 300)
    assert 150 <= len(out_xyz) <= 300
    assert out_fg.any() and (~out_fg).any()
    assert (out_xyz[out_fg, 0] > 0.5 - 1e-9).all() and (out_xyz[~out_fg, 0] <= 0.5).all()
    assert abs(out_rgb.mean() - rgb.mean()) < 0.05
    again = voxel_downsample(xyz, rgb, is_fg, 300)
    assert all(np.array_equal(a, b) for a, b in zip(again, (out_xyz, out_rgb, out_fg), strict=True))
    assert voxel_downsample(xyz, rgb, is_fg, 5000)[0] is xyz


def test_an_oversized_tensor_evicts_nothing():
    cache = TensorCache(budget_mb=2 * 1024 / 2**20)  # two 256-float tensors
    for key in "ab":
        cache.get(key, lambda: torch.zeros(256))
    big = cache.get("big", lambda: torch.zeros(768))  # 1.5x the 2048-byte budget
    assert big.numel() == 768
    assert len(cache) == 2 and cache.used_bytes == 2 * 1024
    kept = torch.ones(1)
    assert cache.get("a", lambda: kept) is not kept  # still cached, not reloaded
