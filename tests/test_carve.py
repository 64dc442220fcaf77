"""Visual hull of residual masks, and the relay stage's carved starting copies."""

import math

import pytest
import torch

from conftest import stage_smoke_cfg
from relaygs.data import Camera
from relaygs.errors import InputError
from relaygs.model import GaussianSet
from relaygs.stages import SPECS
from relaygs.stages.carve import (
    MAX_FINE_CANDIDATES,
    MAX_REFINED_VOXELS,
    MAX_SUBDIVISIONS,
    MIN_CAMERAS,
    SUBDIVISIONS,
    BackgroundRenders,
    HullSettings,
    _consistent,
    finer_subdivisions,
    residual_masks,
    visual_hull,
)
from relaygs.train.render import part_of, splat
from relaygs.train.scene_model import SEGMENT, SceneModel
from splat_scenes import dome_cameras

EPS2D = 0.3  # screen blur of these renders (px², the rasterizer's default)

WIDTH, HEIGHT = 80, 45
BOUNDS = torch.tensor([[-3.0, -3.0, 0.0], [3.0, 3.0, 2.5]])


def _sphere_masks(cameras: list[Camera], center: torch.Tensor, radius: float) -> torch.Tensor:
    """Exact silhouettes of a sphere: pixels whose ray passes within `radius` of `center`."""
    rows, columns = torch.meshgrid(
        torch.arange(HEIGHT) + 0.5, torch.arange(WIDTH) + 0.5, indexing="ij"
    )
    masks = []
    for camera in cameras:
        pixels = torch.stack([columns, rows, torch.ones_like(rows)], dim=-1)
        rays = pixels @ torch.linalg.inv(camera.K).T @ camera.w2c[:3, :3]
        rays = rays / rays.norm(dim=-1, keepdim=True)
        to_center = center - camera.center
        along = rays @ to_center
        distance = (to_center.norm() ** 2 - along**2).clamp_min(0).sqrt()
        masks.append((distance < radius) & (along > 0))
    return torch.stack(masks)


def test_hull_of_a_sphere_lies_on_the_sphere() -> None:
    cameras = dome_cameras(WIDTH, HEIGHT)
    center, radius = torch.tensor([0.8, -0.4, 1.0]), 0.35
    masks = _sphere_masks(cameras, center, radius)
    images = torch.zeros(len(cameras), HEIGHT, WIDTH, 3)
    images[masks] = torch.tensor([0.9, 0.2, 0.1])
    points, colors, size = visual_hull(masks, images, cameras, BOUNDS, HullSettings(misses=0.0))
    assert len(points) > 50
    distance = (points - center).norm(dim=1)
    # a visual hull contains the object and hugs it within a pixel's footprint or so
    assert float(distance.max()) < radius + 0.25
    assert float((distance < radius).float().mean()) > 0.5
    assert torch.allclose(colors, torch.tensor([0.9, 0.2, 0.1]).expand_as(colors))
    assert 0 < size < 0.2


def test_a_small_mover_is_refined_to_the_points_wanted() -> None:
    cameras = dome_cameras(WIDTH, HEIGHT)
    center, radius = torch.tensor([0.5, 0.3, 1.2]), 0.2
    masks = _sphere_masks(cameras, center, radius)
    images = torch.zeros(len(cameras), HEIGHT, WIDTH, 3)
    one_pass = HullSettings(coarse_voxels=24, misses=0.0)
    coarse, _, coarse_size = visual_hull(masks, images, cameras, BOUNDS, one_pass)
    wanted = HullSettings(coarse_voxels=24, misses=0.0, target_points=8 * len(coarse))
    fine, _, fine_size = visual_hull(masks, images, cameras, BOUNDS, wanted)
    assert 0 < len(coarse) < 8 * len(coarse) / 2 < len(fine)
    assert fine_size < coarse_size
    assert float((fine - center).norm(dim=1).max()) < radius + 2 * coarse_size
    # enough points already: the first pass stands
    enough = HullSettings(coarse_voxels=24, misses=0.0, target_points=len(coarse))
    assert torch.equal(visual_hull(masks, images, cameras, BOUNDS, enough)[0], coarse)


@pytest.mark.parametrize(
    ("misses", "seen_fraction"), [(0.0, 0.0), (0.15, 0.0), (0.4, 0.0), (0.15, 0.5)]
)
def test_points_dropped_early_are_those_every_camera_would_reject(misses, seen_fraction) -> None:
    """The early drop keeps exactly the points (and colours) of counting every camera."""
    cameras = dome_cameras(WIDTH, HEIGHT)
    generator = torch.Generator().manual_seed(3)
    masks = _sphere_masks(cameras, torch.tensor([0.2, 0.1, 1.0]), 0.8)
    masks ^= torch.rand(masks.shape, generator=generator) < 0.02  # a noisy silhouette
    images = torch.rand(len(cameras), HEIGHT, WIDTH, 3, generator=generator)
    points = BOUNDS[0] + (BOUNDS[1] - BOUNDS[0]) * torch.rand(20000, 3, generator=generator)
    seen = torch.zeros(len(points), dtype=torch.int64)
    hits = torch.zeros(len(points), dtype=torch.int64)
    color_sum = torch.zeros(len(points), 3)
    for index, camera in enumerate(cameras):
        pixels, inside = camera.project(points, min_depth=0.1 * camera.near)
        column = pixels[:, 0].floor().long().clamp(0, WIDTH - 1)
        row = pixels[:, 1].floor().long().clamp(0, HEIGHT - 1)
        hit = inside & masks[index][row, column]
        seen, hits = seen + inside.long(), hits + hit.long()
        color_sum += images[index][row, column] * hit[:, None].float()
    settings = HullSettings(misses=misses, seen=seen_fraction)
    needed = max(MIN_CAMERAS, math.ceil(seen_fraction * len(cameras)))
    expected = (seen >= needed) & (seen - hits <= (misses * seen.float()).floor().long())
    keep, colors = _consistent(points, masks, cameras, settings, images)
    assert 50 < int(expected.sum()) < len(points) // 2
    assert torch.equal(keep, expected)
    assert torch.equal(colors[keep], (color_sum / hits.clamp_min(1)[:, None].float())[keep])


@pytest.mark.parametrize(
    ("seen", "cameras", "needed"), [(0.5, 27, 14), (0.0, 27, MIN_CAMERAS), (1.0, 5, 5), (0.5, 4, 3)]
)
def test_cameras_needed_is_the_seen_fraction_and_min_cameras_at_least(seen, cameras, needed):
    assert HullSettings(seen=seen).cameras_needed(cameras) == needed


def test_a_region_few_cameras_see_is_no_hull_at_the_default_seen_fraction() -> None:
    """Silhouettes that every camera shows of a blob off to the side: only the cameras that see
    its corner of the bounds count, so at seen 0 a wide cone of voxels passes; at 0.5 nothing."""
    cameras = dome_cameras(WIDTH, HEIGHT)
    center = torch.tensor([0.0, 0.0, 1.0])
    masks = _sphere_masks(cameras, center, 0.3)
    images = torch.zeros(len(cameras), HEIGHT, WIDTH, 3)
    corner = torch.tensor([[4.8, 4.8, 2.8], [5.2, 5.2, 3.2]])  # 5 of 31 cameras see it
    for settings, expect_points in ((HullSettings(seen=0.0), True), (HullSettings(), False)):
        edge = visual_hull(torch.ones_like(masks), images, cameras, corner, settings)[0]
        assert (len(edge) > 0) == expect_points
    # the mover in the middle, seen by every camera, stays
    middle = visual_hull(masks, images, cameras, BOUNDS, HullSettings())[0]
    assert len(middle) > 20 and float((middle - center).norm(dim=1).max()) < 0.6


@pytest.mark.parametrize(
    ("kept", "wanted", "coarse", "expected"),
    [
        (100, None, 10, SUBDIVISIONS),
        (0, 1000, 10, SUBDIVISIONS),
        (1000, 1000, 10, SUBDIVISIONS),
        (100, 800, 10, 2 * SUBDIVISIONS),  # 8× the points: twice the sub-voxels per axis
        (1, 10**9, 1, MAX_SUBDIVISIONS),
        (1, 10**9, 1000, int((MAX_FINE_CANDIDATES / 1000) ** (1 / 3))),
    ],
    ids=["no target", "nothing kept", "enough", "8x", "bounded", "affordable"],
)
def test_finer_subdivisions_grow_with_the_cube_root_and_stay_bounded(
    kept, wanted, coarse, expected
) -> None:
    assert finer_subdivisions(kept, wanted, coarse) == expected


def test_hull_is_empty_without_residual_and_tolerates_one_wrong_camera() -> None:
    cameras = dome_cameras(WIDTH, HEIGHT)
    images = torch.zeros(len(cameras), HEIGHT, WIDTH, 3)
    empty = torch.zeros(len(cameras), HEIGHT, WIDTH, dtype=torch.bool)
    assert len(visual_hull(empty, images, cameras, BOUNDS, HullSettings())[0]) == 0
    masks = _sphere_masks(cameras, torch.tensor([0.0, 0.0, 1.0]), 0.3)
    masks[0] = False  # one camera misses the object (e.g. an occluder)
    strict = visual_hull(masks, images, cameras, BOUNDS, HullSettings(misses=0.0))[0]
    tolerant = visual_hull(masks, images, cameras, BOUNDS, HullSettings(misses=0.15))[0]
    assert len(tolerant) > max(len(strict), 20)


def test_hull_of_an_all_residual_view_refines_a_bounded_random_subset() -> None:
    cameras = dome_cameras(WIDTH, HEIGHT)
    images = torch.zeros(len(cameras), HEIGHT, WIDTH, 3)
    everything = torch.ones(len(cameras), HEIGHT, WIDTH, dtype=torch.bool)
    settings = HullSettings(coarse_voxels=64)
    first = visual_hull(everything, images, cameras, BOUNDS, settings, torch.Generator())[0]
    again = visual_hull(everything, images, cameras, BOUNDS, settings, torch.Generator())[0]
    assert MAX_REFINED_VOXELS < len(first) <= MAX_REFINED_VOXELS * SUBDIVISIONS**3
    assert torch.equal(first, again)


def test_background_renders_each_camera_once_and_match_a_direct_render() -> None:
    cameras = dome_cameras(WIDTH, HEIGHT)[:3]
    background = GaussianSet.from_points(
        torch.rand(200, 3) * 2 - 1, torch.rand(200, 3), max_sh_degree=0, init_opacity=0.5
    )
    part = part_of("bg", background, 0, frozen=True)
    direct = [splat([part], [camera], 0, eps2d=EPS2D).images[0] for camera in cameras]
    renders = BackgroundRenders(background, EPS2D)
    first = renders.images(cameras)
    assert torch.equal(first, torch.stack(direct).clamp(0.0, 1.0))
    background.params["sh_dc"].data.zero_()  # a cached camera is not rendered again
    assert torch.equal(renders.images(cameras[::-1]), first.flip(0))
    moved = Camera(0, cameras[0].K, cameras[1].w2c, WIDTH, HEIGHT)  # same id, new pose
    assert not torch.equal(renders.images([moved])[0], first[0])


def test_residual_masks_ignore_a_camera_gain_but_see_an_object() -> None:
    render = torch.rand(2, 10, 12, 3) * 0.5 + 0.25
    image = render * torch.tensor([1.15, 0.9, 1.0])  # colour response of the camera
    image[1, 2:5, 3:6] = torch.tensor([0.0, 1.0, 0.0])
    masks = residual_masks(render, image, 0.15)
    assert not masks[0].any()
    assert masks[1, 2:5, 3:6].all()
    assert int(masks[1].sum()) == 9


def test_carved_copies_one_per_segment_capped_and_replica_when_nothing_moves(
    stage_scene, stage_decoupled
):
    upstream = {"decouple": stage_decoupled}
    relay = {"steps": 1, "seed_copies": "carve", "seed_points": 40, "hull_residual": 0.1}
    carved = SceneModel.from_artifact(
        SPECS["relay"].run(stage_scene, upstream, stage_smoke_cfg(relay=relay))
    )
    segments = carved.foreground.buffers[SEGMENT]
    per_segment = torch.bincount(segments.long(), minlength=carved.num_segments)
    assert carved.num_segments == 2
    assert all(0 < int(count) <= 40 for count in per_segment)
    assert torch.isfinite(carved.foreground.means).all()
    # nothing exceeds a residual of 0.99: every hull is empty and each copy is the replica
    relay = {"steps": 1, "seed_copies": "carve", "hull_residual": 0.99}
    fallback = SceneModel.from_artifact(
        SPECS["relay"].run(stage_scene, upstream, stage_smoke_cfg(relay=relay))
    )
    replicated = SceneModel.from_artifact(
        SPECS["relay"].run(
            stage_scene, upstream, stage_smoke_cfg(relay={"steps": 1, "seed_copies": "replicate"})
        )
    )
    assert len(fallback.foreground) == len(replicated.foreground)
    assert torch.equal(fallback.foreground.buffers[SEGMENT], replicated.foreground.buffers[SEGMENT])


@pytest.mark.parametrize(
    ("short", "bounds"),
    [
        (True, BOUNDS),
        (False, [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]]),
        (False, [[0.0, 0.0, 0.0], [float("nan"), 1.0, 1.0]]),
    ],
    ids=["a mask short", "a point", "nan"],
)
def test_hull_of_masks_off_the_cameras_or_within_empty_bounds_is_refused(short, bounds) -> None:
    cameras = dome_cameras(WIDTH, HEIGHT)
    count = len(cameras) - short
    masks = torch.ones(count, HEIGHT, WIDTH, dtype=torch.bool)
    images = torch.zeros(count, HEIGHT, WIDTH, 3)
    with pytest.raises(InputError, match="visual_hull: "):
        visual_hull(masks, images, cameras, torch.as_tensor(bounds), HullSettings())
