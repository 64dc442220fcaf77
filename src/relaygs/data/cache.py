"""A thread-safe least-recently-used cache of tensors bounded by a byte budget."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

import torch


class TensorCache:
    """Recently used tensors up to `budget_mb`, oldest evicted first (one over the budget is not
    kept); a pickled cache keeps only its budget, so each worker starts empty."""

    def __init__(self, budget_mb: float) -> None:
        """An empty cache of `budget_mb` megabytes (finite, as `make_options` checks)."""
        self.budget_bytes = int(budget_mb * 2**20)
        self._entries: OrderedDict[Hashable, torch.Tensor] = OrderedDict()
        self._used_bytes = 0
        self._lock = threading.Lock()

    @property
    def used_bytes(self) -> int:
        return self._used_bytes

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, key: Hashable, load: Callable[[], torch.Tensor]) -> torch.Tensor:
        """Return the cached tensor for `key`, calling `load` to make it on a miss."""
        with self._lock:
            if key in self._entries:
                self._entries.move_to_end(key)
                return self._entries[key]
        value = load()
        size = value.element_size() * value.nelement()
        if size > self.budget_bytes:
            return value
        with self._lock:
            if key not in self._entries:
                self._entries[key] = value
                self._used_bytes += size
            while self._used_bytes > self.budget_bytes:
                _, evicted = self._entries.popitem(last=False)
                self._used_bytes -= evicted.element_size() * evicted.nelement()
        return value

    def __getstate__(self) -> dict[str, Any]:
        return {"budget_bytes": self.budget_bytes}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["budget_bytes"] / 2**20)
