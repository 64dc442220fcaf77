"""Gaussian model: parameter set and activations, optimiser groups, density control, guard."""

from relaygs.model.density import (
    BACKGROUND_DENSIFY,
    FOREGROUND_DENSIFY,
    DensifyReport,
    DensifySettings,
    DensityController,
    paper_schedule,
)
from relaygs.model.gaussians import (
    CORE_PARAMS,
    MAX_LOG_SCALE,
    SH_C0,
    GaussianSet,
    inverse_sigmoid,
    normalize_quats,
    sh_degree_for_step,
    sh_of_degree,
)
from relaygs.model.guard import check_finite
from relaygs.model.knn import mean_sq_knn_distance
from relaygs.model.optim import GaussianOptimizer, LRSchedule, SetLearningRates, adam, log_linear

__all__ = [
    "BACKGROUND_DENSIFY",
    "CORE_PARAMS",
    "FOREGROUND_DENSIFY",
    "MAX_LOG_SCALE",
    "SH_C0",
    "DensifyReport",
    "DensifySettings",
    "DensityController",
    "GaussianOptimizer",
    "GaussianSet",
    "LRSchedule",
    "SetLearningRates",
    "adam",
    "check_finite",
    "inverse_sigmoid",
    "log_linear",
    "mean_sq_knn_distance",
    "normalize_quats",
    "paper_schedule",
    "sh_degree_for_step",
    "sh_of_degree",
]
