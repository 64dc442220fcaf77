"""The native CPU path of the splatting core: C++ kernels for binning and compositing
(forward and backward), built on first use (`build`), behind the same contracts as the
torch path (`relaygs.splat.tiles`, `relaygs.splat.composite`)."""

from relaygs.splat.native.build import NativeUnavailableError, available, load, supports

__all__ = ["NativeUnavailableError", "available", "load", "supports"]
