"""A tensor computed on first use, so that a rollout encodes only the states the policy reads.

The preprocessor sees every observation, but the policy reads only the `n_obs_steps` observations before
each new chunk: with 8 actions per chunk, 6 of every 8 GaLR encodes of the hand state would be thrown
away. At inference the preprocessor therefore hands the policy a `DeferredTensor` for the state; the
policy's observation queue holds it, and stacking the queue for a new chunk computes it. Any torch
operation computes it first and then runs on the real tensor, so it cannot be read as anything else.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch.utils._pytree import tree_map


class DeferredTensor(torch.Tensor):
    """Stands for `compute()`, a tensor of the given shape, dtype and device; computed once, when first
    used, and kept."""

    @staticmethod
    def __new__(cls, compute: Callable[[], torch.Tensor], shape, dtype, device):
        return torch.Tensor._make_wrapper_subclass(cls, shape, dtype=dtype, device=device)

    def __init__(self, compute: Callable[[], torch.Tensor], shape, dtype, device):
        self._compute: Callable[[], torch.Tensor] | None = compute
        self._value: torch.Tensor | None = None

    def value(self) -> torch.Tensor:
        if self._value is None:
            value = self._compute()
            if value.shape != self.shape:
                raise RuntimeError(f"a deferred {tuple(self.shape)} tensor computed {tuple(value.shape)}")
            self._value, self._compute = value, None
        return self._value

    def then(self, function: Callable[[torch.Tensor], torch.Tensor]) -> DeferredTensor:
        """`function` of this tensor's value (same shape), itself deferred."""
        return DeferredTensor(lambda: function(self.value()), self.shape, self.dtype, self.device)

    @property
    def computed(self) -> bool:
        return self._value is not None

    __torch_function__ = torch._C._disabled_torch_function_impl

    @classmethod
    def __torch_dispatch__(cls, func, types, args=(), kwargs=None):
        def real(x):
            return x.value() if isinstance(x, DeferredTensor) else x

        return func(*tree_map(real, args), **tree_map(real, kwargs or {}))

    def __repr__(self) -> str:
        return f"DeferredTensor(shape={tuple(self.shape)}, computed={self.computed})"


def defer(compute: Callable[[], torch.Tensor], like: torch.Tensor, width: int) -> DeferredTensor:
    """`compute()` deferred, for a (B, width) result on `like`'s device and dtype."""
    return DeferredTensor(compute, (*like.shape[:-1], width), like.dtype, like.device)
