"""Which array library an array comes from: numpy, or torch (never imported here).

Functions that take both (normals, rasterisation) pick their path with :func:`is_torch`, so
that ``import morphable`` and numpy callers never load torch.
"""
from __future__ import annotations

__all__ = ["is_torch"]


def is_torch(x) -> bool:
    """True for a torch tensor (judged by its type's module: torch is not imported)."""
    return type(x).__module__.split(".")[0] == "torch"
