"""relaygs: dynamic 3D Gaussian splatting with Relay Gaussians, as an experiment framework."""

__version__ = "0.1.0"
