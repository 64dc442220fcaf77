"""Split nested training state (optimizer state dicts, RNG states) into tensors and a tagged
JSON skeleton (int dict keys, tuples, numpy arrays) that decodes exactly, without pickle."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

TENSOR_TAG = "$tensor"
DICT_TAG = "$dict"
TUPLE_TAG = "$tuple"
NDARRAY_TAG = "$ndarray"


def encode_tree(
    value: Any,
    tensors: dict[str, torch.Tensor],
    prefix: str,
    where: str,
    places: dict[str, str] | None = None,
) -> Any:
    """JSON-able skeleton of `value`, its tensors added to `tensors` as `<prefix><n>` (CPU
    copies); `places` gets each one's `where` (e.g. `optimizers['mlp']['state'][0]`)."""
    if isinstance(value, torch.Tensor):
        name = f"{prefix}{len(tensors)}"
        tensors[name] = value.detach().to("cpu").clone(memory_format=torch.contiguous_format)
        if places is not None:
            places[name] = where
        return {TENSOR_TAG: name}
    if isinstance(value, dict):
        return {
            DICT_TAG: [
                [
                    encode_tree(key, tensors, prefix, f"{where} key", places),
                    encode_tree(item, tensors, prefix, f"{where}[{key!r}]", places),
                ]
                for key, item in value.items()
            ]
        }
    if isinstance(value, tuple):
        return {TUPLE_TAG: encode_tree(list(value), tensors, prefix, where, places)}
    if isinstance(value, list):
        return [
            encode_tree(item, tensors, prefix, f"{where}[{i}]", places)
            for i, item in enumerate(value)
        ]
    if isinstance(value, np.ndarray):
        return {
            NDARRAY_TAG: {
                "dtype": value.dtype.str,
                "shape": list(value.shape),
                "data": value.ravel().tolist(),
            }
        }
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, str | bool | int | float):
        return value
    raise TypeError(f"{where}: cannot checkpoint a {type(value).__name__} (no pickle is used)")


def decode_tree(skeleton: Any, tensors: dict[str, torch.Tensor]) -> Any:
    """Inverse of `encode_tree`: rebuild the original tree from its skeleton and tensors."""
    if isinstance(skeleton, list):
        return [decode_tree(item, tensors) for item in skeleton]
    if not isinstance(skeleton, dict):
        return skeleton
    if TENSOR_TAG in skeleton:
        return tensors[skeleton[TENSOR_TAG]]
    if DICT_TAG in skeleton:
        return {
            decode_tree(key, tensors): decode_tree(item, tensors)
            for key, item in skeleton[DICT_TAG]
        }
    if TUPLE_TAG in skeleton:
        return tuple(decode_tree(item, tensors) for item in skeleton[TUPLE_TAG])
    if NDARRAY_TAG in skeleton:
        spec = skeleton[NDARRAY_TAG]
        return np.array(spec["data"], dtype=np.dtype(spec["dtype"])).reshape(spec["shape"])
    raise ValueError(f"unknown tagged value in checkpoint state: {sorted(skeleton)}")
