"""The native CPU splatting kernels (binning, compositing forward and backward), built from
this folder's C++ source on first use, then cached.

`load()` returns the compiled module, or raises NativeUnavailableError with a one-line reason
(no C++ compiler, no ninja, a compile error with the log's path). The build goes to torch's
extension folder (`TORCH_EXTENSIONS_DIR`, default ~/.cache/torch_extensions) under a name
that hashes the source, the flags, the torch and Python versions and this CPU, so a changed
source, another torch install or another machine sharing the folder gets its own build,
compiled for the CPU it runs on, while checkouts of the same source share one (it is built
from a copy in that folder). A build says so in one line first.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import platform
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import torch
from filelock import FileLock

HERE = Path(__file__).parent
SOURCES = [
    HERE / "module.cpp",
    HERE / "binning.cpp",
    HERE / "composite.cpp",
    HERE / "projection.cpp",
    HERE / "hexplane.cpp",
    HERE / "smoothness.cpp",
    HERE / "ssim.cpp",
    HERE / "nearest.cpp",
]
HEADERS = [HERE / "kernels.h"]
# -fopenmp compiles at::parallel_for's OpenMP region (without it the loop runs on one
# thread); the process already holds torch's libgomp, which the kernel then shares.
# -ffp-contract=off: no fused multiply-adds, so the forward and the backward, which evaluate
# each pair in separately inlined copies of one function, round it identically and agree on
# which pairs pass the 1/255 and power >= 0 tests.
CFLAGS = ["-O3", "-march=native", "-fopenmp", "-fno-math-errno", "-ffp-contract=off"]


class NativeUnavailableError(RuntimeError):
    """The native kernel cannot be built or loaded here; the message says why in one line."""


def _cpu_signature() -> str:
    """What -march=native compiles for: the CPU's model and flags (Linux), else the machine."""
    try:
        text = Path("/proc/cpuinfo").read_text(errors="replace")
    except OSError:
        return platform.machine()
    keep = [line for line in text.splitlines() if line.startswith(("model name", "flags"))]
    return "\n".join(sorted(set(keep))) or platform.machine()


def build_name() -> str:
    """Extension name unique to this source, flags, torch (version and install), Python and
    CPU."""
    digest = hashlib.sha256()
    for path in (*SOURCES, *HEADERS):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    digest.update(" ".join(CFLAGS).encode())
    digest.update(torch.__version__.encode())
    # the headers' paths enter ninja's command lines: another torch install builds its own
    digest.update(str(Path(torch.__file__).resolve().parent).encode())
    digest.update(sys.implementation.cache_tag.encode())  # the Python ABI it links against
    digest.update(_cpu_signature().encode())
    return f"relaygs_splat_{digest.hexdigest()[:12]}"


def build_folder(name: str) -> Path:
    """Where extension `name` is built and cached: torch's extension folder
    ($TORCH_EXTENSIONS_DIR, default ~/.cache/torch_extensions)."""
    root = os.environ.get("TORCH_EXTENSIONS_DIR") or Path.home() / ".cache" / "torch_extensions"
    return Path(root) / name


def _copy_sources(target: Path) -> list[Path]:
    """The sources and headers copied into `target` (unchanged files left alone): ninja
    rebuilds whenever the sources' paths change, so every checkout builds from this one
    place and shares the cached build of the same source."""
    target.mkdir(exist_ok=True)
    for path in (*SOURCES, *HEADERS):
        copy = target / path.name
        if not copy.is_file() or copy.read_bytes() != path.read_bytes():
            shutil.copyfile(path, copy)
    return [target / path.name for path in SOURCES]


@contextlib.contextmanager
def _exclusive(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on `path` (released by the OS if this process dies)."""
    with FileLock(path):
        yield


def compiler() -> str | None:
    """Path of the C++ compiler torch's build would call ($CXX, else c++), or None."""
    return shutil.which(os.environ.get("CXX", "c++"))


def _ninja_available() -> bool:
    """Whether torch's build finds `ninja` on PATH; the `ninja` package's own binary (a
    dependency, in the venv's bin folder, which is not on PATH unless the venv is active)
    is put there first when PATH has none."""
    from torch.utils.cpp_extension import is_ninja_available

    if shutil.which("ninja") is None:
        try:
            import ninja
        except ImportError:
            return False
        os.environ["PATH"] = os.pathsep.join([ninja.BIN_DIR, os.environ.get("PATH", "")])
    return is_ninja_available()


def load() -> ModuleType:
    """The compiled kernel module, built on the process's first call; a failure is kept
    and raised again (NativeUnavailableError) without another build attempt."""
    module, reason = _build_once()
    if module is None:
        raise NativeUnavailableError(reason)
    return module


@functools.cache
def _build_once() -> tuple[ModuleType | None, str]:
    """(module, "") or (None, why it cannot be had): one build attempt per process."""
    if compiler() is None:
        return (
            None,
            f"no C++ compiler found ({os.environ.get('CXX', 'c++')}; set CXX or install g++)",
        )
    if not _ninja_available():
        return None, "ninja not found (pip install ninja)"
    from torch.utils.cpp_extension import load as build

    name = build_name()
    folder = build_folder(name)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with _exclusive(folder / "relaygs.lock"):
            if not (folder / f"{name}.so").is_file():
                print(
                    "relaygs: building the native splatting kernels for this CPU (once, one to "
                    f"two minutes on 2 cores) in {folder}",
                    file=sys.stderr,
                    flush=True,
                )
            # torch's own lock file outlives a builder killed mid-build and would make every
            # later build wait forever; under our lock no other build can be running
            (folder / "lock").unlink(missing_ok=True)
            sources = _copy_sources(folder / "src")
            module = build(
                name=name,
                sources=[str(path) for path in sources],
                extra_cflags=CFLAGS,
                extra_ldflags=["-fopenmp"],
                build_directory=str(folder),
                verbose=False,
            )
    except (RuntimeError, OSError, ImportError) as err:
        log = Path(tempfile.gettempdir()) / f"{name}-build.log"
        try:
            log.write_text(str(err))
            where = f"log: {log}"
        except OSError:
            where = "its log could not be written"
        return None, f"the kernel failed to build ({type(err).__name__}; {where})"
    return module, ""


@functools.cache
def _warn_fallback(reason: str) -> None:
    print(
        f"relaygs: native CPU splatting kernels unavailable: {reason}; using the torch path "
        "(5-8x slower renders, about 2x slower training)",
        file=sys.stderr,
    )


def available() -> bool:
    """True when the kernel loads; the first failure prints one line saying why."""
    try:
        load()
    except NativeUnavailableError as err:
        _warn_fallback(str(err))
        return False
    return True


def supports(tensor: torch.Tensor) -> bool:
    """Whether the kernel handles renders of this tensor's device and dtype."""
    return tensor.device.type == "cpu" and tensor.dtype in (torch.float32, torch.float64)
