"""Deformation MLP as in 4D-GS: HexPlane features → a trunk → one head per attribute, giving
deltas of the pre-activation position, scale, rotation and opacity (no SH head)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import torch
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from relaygs.errors import InputError


class Deltas(NamedTuple):
    """Per-Gaussian offsets to pre-activation parameters: dxyz [N,3], dscale [N,3] (log-scale),
    drot [N,4] (wxyz quaternion), dopacity [N,1] (logit)."""

    dxyz: Tensor
    dscale: Tensor
    drot: Tensor
    dopacity: Tensor


HEAD_WIDTHS = {"dxyz": 3, "dscale": 3, "drot": 4, "dopacity": 1}
# a matmul dtype's products: None runs them in the parameters' own dtype (float64 in the tests)
MATMUL_DTYPES = {"float32": None, "bfloat16": torch.bfloat16}


@dataclass(frozen=True)
class HeadSwitches:
    """Which heads predict a delta (4D-GS no_dx/no_ds/no_dr/no_do, inverted); off gives zeros."""

    dxyz: bool = True
    dscale: bool = True
    drot: bool = True
    dopacity: bool = True


def _head(width: int, out: int) -> nn.Sequential:
    last = nn.Linear(width, out)
    # zero last layer: deform starts from the trained static model, so it starts as the
    # identity (4D-GS's Xavier init starts with a random deformation)
    nn.init.zeros_(last.weight)
    nn.init.zeros_(last.bias)
    return nn.Sequential(nn.ReLU(), nn.Linear(width, width), nn.ReLU(), last)


class DeformationMLP(nn.Module):
    """Trunk Linear(feature_dim, W) plus `depth` ReLU→Linear(W, W) layers, then the enabled
    heads (4D-GS's multi-view config, defor_depth 0, is depth 0)."""

    def __init__(
        self,
        feature_dim: int,
        *,
        width: int = 128,
        depth: int = 0,
        heads: HeadSwitches = HeadSwitches(),
        matmul_dtype: str = "float32",
    ) -> None:
        """Build the trunk and one head per switched-on attribute; `matmul_dtype` "bfloat16"
        runs the matrix products in bfloat16 (parameters, outputs and gradients stay float32)."""
        super().__init__()
        if feature_dim < 1 or width < 1 or depth < 0:
            raise InputError(
                "DeformationMLP: expected feature_dim >= 1, width >= 1, depth >= 0, got "
                f"{feature_dim}, {width}, {depth}"
            )
        if matmul_dtype not in MATMUL_DTYPES:
            raise InputError(
                f"DeformationMLP matmul_dtype: expected one of {sorted(MATMUL_DTYPES)}, "
                f"got {matmul_dtype!r}"
            )
        self.reduced_dtype = MATMUL_DTYPES[matmul_dtype]
        layers: list[nn.Module] = [nn.Linear(feature_dim, width)]
        for _ in range(depth):
            layers += [nn.ReLU(), nn.Linear(width, width)]
        self.trunk = nn.Sequential(*layers)
        self.heads = nn.ModuleDict(
            {name: _head(width, HEAD_WIDTHS[name]) for name, on in asdict(heads).items() if on}
        )

    def forward(self, features: Tensor) -> Deltas:
        """Deltas for features [N, feature_dim]; a switched-off head returns zeros."""
        count = features.shape[0]
        compute_dtype = self.reduced_dtype or features.dtype
        if len(self.trunk) == 1 and self.heads:
            trunk = self.trunk[0]
            head_params = [
                t
                for head in self.heads.values()
                for t in (*head[1].parameters(), *head[3].parameters())
            ]
            outputs = dict(
                zip(
                    self.heads,
                    _SingleLayerMLP.apply(
                        compute_dtype, features, trunk.weight, trunk.bias, *head_params
                    ),
                    strict=True,
                )
            )
        else:
            reduced = compute_dtype != features.dtype
            with torch.autocast(features.device.type, compute_dtype, enabled=reduced):
                # every head starts with ReLU(hidden): apply it once, then each head's others
                shared = torch.relu(self.trunk(features))
                outputs = {
                    name: head[1:](shared).to(features.dtype) for name, head in self.heads.items()
                }
        return Deltas(
            **{
                name: outputs[name] if name in outputs else features.new_zeros(count, out)
                for name, out in HEAD_WIDTHS.items()
            }
        )


class _SingleLayerMLP(torch.autograd.Function):
    """A depth-0 DeformationMLP as one autograd node (head parameters as (w1, b1, w2, b2) each):
    in-place ReLUs, and one GEMM-summed buffer for the shared layer's gradient, not one per head.
    Products run in `compute_dtype`; outputs and gradients come back in the features' dtype."""

    @staticmethod
    def forward(
        ctx: Any,
        compute_dtype: torch.dtype,
        features: Tensor,
        trunk_weight: Tensor,
        trunk_bias: Tensor,
        *head_params: Tensor,
    ) -> tuple[Tensor, ...]:
        result_dtype = features.dtype
        features, trunk_weight, trunk_bias, *head_params = (
            t.to(compute_dtype) for t in (features, trunk_weight, trunk_bias, *head_params)
        )
        shared = torch.addmm(trunk_bias, features, trunk_weight.t()).relu_()
        hidden, outputs = [], []
        for w1, b1, w2, b2 in _per_head(head_params):
            h = torch.addmm(b1, shared, w1.t()).relu_()
            hidden.append(h)
            outputs.append(torch.addmm(b2, h, w2.t()).to(result_dtype))
        ctx.save_for_backward(features, trunk_weight, shared, *head_params, *hidden)
        ctx.heads = len(hidden)
        ctx.result_dtype = result_dtype
        return tuple(outputs)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, *grads: Tensor) -> tuple[Tensor | None, ...]:
        features, trunk_weight, shared, *rest = ctx.saved_tensors
        head_params, hidden = rest[: 4 * ctx.heads], rest[4 * ctx.heads :]
        grad_shared = torch.zeros_like(shared)
        head_grads: list[Tensor] = []
        for (w1, _, w2, _), h, grad in zip(_per_head(head_params), hidden, grads, strict=True):
            grad = h.new_zeros(h.shape[0], w2.shape[0]) if grad is None else grad.to(h.dtype)
            grad_h = _relu_backward(grad @ w2, h)
            grad_shared.addmm_(grad_h, w1)
            head_grads += [grad_h.t() @ shared, grad_h.sum(0), grad.t() @ h, grad.sum(0)]
        grad_shared = _relu_backward(grad_shared, shared)
        grad_features = grad_shared @ trunk_weight if ctx.needs_input_grad[1] else None
        trunk_grads = (grad_shared.t() @ features, grad_shared.sum(0))
        return (
            None,
            *(
                None if grad is None else grad.to(ctx.result_dtype)
                for grad in (grad_features, *trunk_grads, *head_grads)
            ),
        )


def _relu_backward(grad: Tensor, result: Tensor) -> Tensor:
    """grad where the ReLU's `result` is positive, else 0 (ATen's own ReLU backward)."""
    return torch.ops.aten.threshold_backward(grad, result, 0.0)


def _per_head(params: tuple[Tensor, ...] | list[Tensor]) -> list[tuple[Tensor, ...]]:
    return [tuple(params[i : i + 4]) for i in range(0, len(params), 4)]
