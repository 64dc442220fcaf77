"""Nearest neighbours: the native kernel against torch's cdist, ties, sizes, thread counts."""

from __future__ import annotations

import pytest
import torch

from relaygs.nearest import nearest_indices, nearest_indices_torch
from relaygs.stages.frame_hulls import FrameHulls


def _cloud(count: int, seed: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    return torch.randn(count, 3, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def _squared(queries: torch.Tensor, points: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    return (queries.double() - points.double()[index]).square().sum(dim=1)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize(("queries", "points"), [(0, 5), (1, 1), (37, 15), (300, 1025)])
def test_each_query_gets_its_nearest_point(
    splat_backend: str, dtype: torch.dtype, queries: int, points: int
) -> None:
    q, p = _cloud(queries, 1, dtype), _cloud(points, 2, dtype)
    got = nearest_indices(q, p)
    assert got.dtype == torch.int64 and got.shape == (queries,)
    # the exact nearest distance, in float64 over every pair
    best = (q.double()[:, None] - p.double()[None]).square().sum(dim=2).amin(dim=1)
    torch.testing.assert_close(_squared(q, p, got), best, rtol=1e-6, atol=1e-12)


def test_ties_go_to_the_first_point_and_threads_do_not_change_it(splat_backend: str) -> None:
    points = _cloud(40, 3).repeat(3, 1)  # every point three times: rows i, i + 40, i + 80
    queries = torch.cat([points[:40], _cloud(200, 4)])
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = nearest_indices(queries, points)
        torch.set_num_threads(2)
        two = nearest_indices(queries, points)
    finally:
        torch.set_num_threads(threads)
    torch.testing.assert_close(one, two, rtol=0, atol=0)
    torch.testing.assert_close(one[:40], torch.arange(40), rtol=0, atol=0)
    assert (one < 40).all()  # a duplicate never wins over its first copy
    torch.testing.assert_close(one, nearest_indices_torch(queries, points), rtol=0, atol=0)


def test_the_hull_distance_is_the_same_on_both_paths(splat_backend: str) -> None:
    means = _cloud(500, 5).requires_grad_(True)
    hulls = FrameHulls({0: _cloud(700, 6) * 0.5}, {0: 0.05})
    value = hulls.distance(means, 0, coverage=1.0)
    (grad,) = torch.autograd.grad(value, means)
    # the same pairs by cdist: the torch path's value and gradient
    reference = means.detach().clone().requires_grad_(True)
    hull = hulls.points[0]
    near = (reference - hull[nearest_indices_torch(reference, hull)]).norm(dim=1)
    far = (reference[nearest_indices_torch(hull, reference)] - hull).norm(dim=1)
    want = (near - 0.05).clamp_min(0).mean() + (far - 0.05).clamp_min(0).mean()
    torch.testing.assert_close(value, want)
    torch.testing.assert_close(grad, torch.autograd.grad(want, reference)[0])
    assert torch.isfinite(grad).all()


def test_an_empty_point_set_is_refused(splat_backend: str) -> None:
    with pytest.raises((RuntimeError, IndexError)):
        nearest_indices(_cloud(3, 7), _cloud(0, 8))
