"""check_finite: passes finite tensors, names the first non-finite tensor or gradient."""

import pytest
import torch

from relaygs.errors import DivergenceError
from relaygs.model import check_finite


def test_finite_tensors_pass_even_where_their_sum_overflows() -> None:
    check_finite("decouple", 3, {"a": torch.ones(3), "b": torch.zeros(2, 2)})
    check_finite("decouple", 3, {})
    huge = torch.full((4,), 3e38)
    assert not torch.isfinite(huge.sum())
    check_finite("deform", 2, {"means": huge, "big64": torch.tensor([1e300], dtype=torch.float64)})


def test_names_stage_step_and_first_bad_tensor() -> None:
    tensors = {"loss": torch.tensor(1.0), "means": torch.tensor([0.0, float("nan")])}
    tensors["scales"] = torch.tensor([float("inf")])
    with pytest.raises(DivergenceError, match=r"'relay'.*step 17.*'means'"):
        check_finite("relay", 17, tensors)


def test_names_non_finite_gradient() -> None:
    param = torch.nn.Parameter(torch.ones(3))
    (param * torch.tensor([1.0, float("inf"), 1.0])).sum().backward()
    with pytest.raises(DivergenceError, match=r"'opacity\.grad'"):
        check_finite("deform", 5, {"opacity": param})


def test_nan_beside_huge_values_is_still_named() -> None:
    tensors = {"means": torch.full((4,), 3e38), "scales": torch.tensor([1.0, float("nan")])}
    with pytest.raises(DivergenceError, match="'scales' has 1 non-finite"):
        check_finite("relay", 9, tensors)
