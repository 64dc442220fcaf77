"""The native CPU kernels: binning equal to the torch path's, renders that do not depend on
the thread count, backend selection, and the fallback where the kernels cannot be built.
(Parity with the reference and the hard cases run on both backends in test_splat_parity.py,
test_splat_numerics.py, test_splat_fixed_layer.py and test_splat_garden.py.)"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest
import torch

from relaygs.errors import InputError
from relaygs.field.hexplane import second_difference_energy
from relaygs.splat import rasterization, use_backend
from relaygs.splat.fused_projection import FusedProjectGaussians
from relaygs.splat.native import build
from relaygs.splat.native.binning import bin_gaussians_native
from relaygs.splat.native.projection import NATIVE_PROJECTION, project_gaussians_native
from relaygs.splat.tiles import bin_gaussians
from splat_scenes import (
    assert_projection_matches_torch,
    projection_inputs,
    random_scene,
    render_and_grads,
    with_grad,
)

pytestmark = pytest.mark.usefixtures("native_kernel")


@pytest.fixture(scope="module")
def native_kernel():
    """The kernels, built (a machine without a C++ compiler skips this module)."""
    if build.compiler() is None:
        pytest.skip("no C++ compiler: the native kernels cannot be built here")
    return build.load()


@pytest.mark.parametrize("tile_size", [3, 8, 16])
@pytest.mark.parametrize(("cams", "width", "height"), [(1, 40, 32), (4, 37, 29)])
def test_native_binning_equals_the_torch_binning(tile_size, cams, width, height):
    scene = random_scene(400, seed=cams, num_cameras=cams, width=width, height=height)
    _, _, meta = rasterization(**scene, backend="torch")
    args = (meta["bounds"], meta["depths"], meta["visible"], width, height, tile_size)
    expected, got = bin_gaussians(*args), bin_gaussians_native(*args)
    assert expected.pair_gaussian.numel() > 500
    for name in ("pair_gaussian", "tile_start", "tile_count"):
        assert torch.equal(getattr(got, name), getattr(expected, name)), name
    counts = got.tile_count[got.busy_tiles]
    assert (counts > 0).all() and (counts[:-1] >= counts[1:]).all()  # longest first
    assert got.busy_tiles.numel() == int((got.tile_count > 0).sum())


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_projection_equals_the_torch_projection(dtype):
    assert_projection_matches_torch(project_gaussians_native, dtype)


def test_native_projection_gradients_match_finite_differences():
    scene = random_scene(12, seed=4, num_cameras=2, dtype=torch.float64)
    means, factors, opacities, viewmats, Ks, width, height = projection_inputs(scene)
    settings = (width, height, 0.01, 1e10, 0.3)
    cameras = (viewmats, Ks, settings)

    def projected(means: torch.Tensor, factors: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = FusedProjectGaussians.apply(NATIVE_PROJECTION, means, factors, opacities, *cameras)
        return out[:3]

    assert torch.autograd.gradcheck(
        projected, (means.requires_grad_(), factors.detach().requires_grad_())
    )


def test_native_projection_of_differentiable_cameras_takes_the_torch_path():
    scene = random_scene(50, seed=1, num_cameras=2)
    viewmats = scene["viewmats"].clone().requires_grad_()
    proj = project_gaussians_native(*projection_inputs({**scene, "viewmats": viewmats}))
    proj.means2d.sum().backward()
    assert viewmats.grad is not None and viewmats.grad.abs().sum() > 0


@pytest.mark.parametrize("tile_size", [3, 5, 7])
def test_odd_tile_sizes_render_as_the_torch_backend(tile_size):
    # tiles of 9, 25 and 49 pixels fill their SIMD vectors partly: padding lanes stay idle
    scene = with_grad(random_scene(150, seed=5, num_cameras=2, width=23, height=19))
    ref = render_and_grads(rasterization, scene, backend="torch")
    got = render_and_grads(rasterization, scene, backend="native", tile_size=tile_size)
    torch.testing.assert_close(got[0], ref[0], rtol=0, atol=1e-5)
    torch.testing.assert_close(got[1], ref[1], rtol=0, atol=1e-5)
    for key, expected in ref[3].items():
        rel = (got[3][key] - expected).norm() / expected.norm()
        assert rel < 1e-4, key


def test_native_renders_do_not_depend_on_the_thread_count():
    scene = with_grad(random_scene(800, seed=3, num_cameras=3, width=48, height=40))
    before = torch.get_num_threads()
    try:
        results = []
        for threads in (1, 2):
            torch.set_num_threads(threads)
            results.append(render_and_grads(rasterization, scene, backend="native"))
    finally:
        torch.set_num_threads(before)
    (colors1, alphas1, _, grads1), (colors2, alphas2, _, grads2) = results
    assert torch.equal(colors1, colors2) and torch.equal(alphas1, alphas2)
    for key, grad in grads1.items():
        assert torch.equal(grad, grads2[key]), key


def test_auto_takes_the_native_kernels_on_cpu():
    scene = random_scene(50, seed=0)
    assert rasterization(**scene)[2]["backend"] == "native"
    assert rasterization(**scene, backend="torch")[2]["backend"] == "torch"


def test_the_process_default_backend_is_what_use_backend_set():
    scene = random_scene(50, seed=0)
    try:
        use_backend("torch")
        assert rasterization(**scene)[2]["backend"] == "torch"
        assert rasterization(**scene, backend="native")[2]["backend"] == "native"
    finally:
        use_backend("auto")
    with pytest.raises(InputError, match=r"splat\.backend"):
        use_backend("fast")


@pytest.mark.parametrize(
    ("backend", "dtype", "names"),
    [("fast", torch.float32, "backend"), ("native", torch.float16, "float16")],
)
def test_a_backend_that_cannot_render_these_tensors_is_refused(backend, dtype, names):
    scene = {k: v.to(dtype) if torch.is_tensor(v) else v for k, v in random_scene(5).items()}
    with pytest.raises(InputError, match=names):
        rasterization(**scene, backend=backend)


def _run(code: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        timeout=300,
    )


def test_without_a_compiler_auto_renders_with_torch_and_says_so_once(tmp_path):
    done = _run(
        """
        import sys
        sys.path.insert(0, "tests")
        from splat_scenes import random_scene
        from relaygs.errors import InputError
        from relaygs.splat import rasterization
        scene = random_scene(30)
        print(rasterization(**scene)[2]["backend"], rasterization(**scene)[2]["backend"])
        try:
            rasterization(**scene, backend="native")
        except InputError as err:
            print("refused:", err)
        """,
        CXX=str(tmp_path / "no-such-compiler"),
        TORCH_EXTENSIONS_DIR=str(tmp_path / "build"),
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == "torch torch"
    assert lines[1].startswith("refused:") and "no-such-compiler" in lines[1]
    warning = [line for line in done.stderr.splitlines() if "native" in line]
    assert len(warning) == 1 and "no C++ compiler" in warning[0], done.stderr


def test_a_kernel_that_fails_to_compile_names_its_log(tmp_path, monkeypatch, capsys):
    broken = tmp_path / "broken.cpp"
    broken.write_text("this is not C++\n")
    monkeypatch.setattr(build, "SOURCES", [broken])
    monkeypatch.setattr(build, "HEADERS", [])
    monkeypatch.setenv("TORCH_EXTENSIONS_DIR", str(tmp_path / "build"))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    module, reason = build._build_once.__wrapped__()
    assert module is None
    log = Path(reason.split("log: ")[1].rstrip(")"))
    assert log.parent == tmp_path and "broken.cpp" in log.read_text()
    assert str(tmp_path / "build") in capsys.readouterr().err  # the build said where it works


def test_the_compositing_vectors_fit_this_cpus_registers(tmp_path):
    """GCC expands vectors wider than the target's registers piecewise, partly lane by lane
    (64-byte vectors ran the compositing 2.6x slower on an AVX2-only CPU): none may be left.
    The kernel is compiled again with the flags of its real build (read from its build.ninja)."""
    cxx = build.compiler()
    macros = subprocess.run(
        [cxx, "-dM", "-E", "-x", "c++", os.devnull], capture_output=True, text=True
    ).stdout
    if "__GNUC__" not in macros or "__clang__" in macros:
        pytest.skip("-Wvector-operation-performance is GCC's")
    ninja_file = build.build_folder(build.build_name()) / "build.ninja"
    (cflags,) = [
        line.split("=", 1)[1]
        for line in ninja_file.read_text().splitlines()
        if line.startswith("cflags =")
    ]
    strict = [*shlex.split(cflags), "-Werror=vector-operation-performance"]
    source, output = build.HERE / "composite.cpp", tmp_path / "composite.o"
    compiled = subprocess.run(
        [cxx, *strict, "-c", str(source), "-o", str(output)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert compiled.returncode == 0, compiled.stderr[-2000:]


def test_the_ninja_package_is_found_when_path_has_no_ninja(tmp_path, monkeypatch):
    ninja = pytest.importorskip("ninja")
    monkeypatch.setenv("PATH", str(tmp_path))  # no ninja here
    assert build._ninja_available()
    assert os.environ["PATH"].split(os.pathsep)[0] == ninja.BIN_DIR


@pytest.mark.parametrize("dims", [(2,), (3,), (2, 3)])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_native_plane_smoothness_equals_the_torch_path(dims, dtype):
    planes = torch.rand(3, 4, 7, 5, dtype=dtype, generator=torch.Generator().manual_seed(len(dims)))
    results = []
    try:
        for backend in ("torch", "native"):
            use_backend(backend)
            leaf = planes.clone().requires_grad_()
            energy = second_difference_energy(leaf, dims)
            (energy * 3.0).backward()
            results.append((energy.detach(), leaf.grad))
    finally:
        use_backend("auto")
    tol = 1e-6 if dtype == torch.float32 else 1e-13
    for got, expected in zip(results[1], results[0], strict=True):
        assert float(expected.abs().max()) > 0
        torch.testing.assert_close(got, expected, rtol=tol, atol=tol)
