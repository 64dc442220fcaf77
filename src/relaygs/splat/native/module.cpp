// Python bindings of the native splatting kernels (built by relaygs.splat.native).
#include <torch/extension.h>

#include "kernels.h"

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  // The kernels touch no Python object: other Python threads (TensorBoard's writer, the
  // scene cache) run while they do.
  using release = py::call_guard<py::gil_scoped_release>;
  m.def("bin_tiles", &relaygs::bin_tiles, "Depth-ordered Gaussian lists per tile", release());
  m.def("composite_forward", &relaygs::composite_forward, "Composite tiles front to back",
        release());
  m.def("composite_backward", &relaygs::composite_backward,
        "Per-Gaussian gradients, tiles walked back to front", release());
  m.def("project_forward", &relaygs::project_forward, "EWA projection into C cameras",
        release());
  m.def("project_backward", &relaygs::project_backward,
        "Mean and covariance-factor gradients of the projection", release());
  m.def("hexplane_forward", &relaygs::hexplane_forward, "HexPlane features of points",
        release());
  m.def("hexplane_backward", &relaygs::hexplane_backward,
        "Plane and coordinate gradients of HexPlane features", release());
  m.def("second_difference", &relaygs::second_difference,
        "Second-difference energy of planes and its gradient", release());
  m.def("nearest_points", &relaygs::nearest_points, "Index of each query's nearest point",
        release());
  m.def("ssim_forward", &relaygs::ssim_forward, "Mean SSIM of image batches", release());
  m.def("ssim_backward", &relaygs::ssim_backward, "SSIM gradient of the first images",
        release());
}
