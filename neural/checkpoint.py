"""Loading a network from a checkpoint file with one-line errors that name the file: the
loader every network of the plugin shares (the GAR's generator, inverter and auxiliary
networks, the landmark network). Where each product's committed weights live is its own
(:mod:`neural.gar.paths`, :func:`neural.landmarks.detector.weights_path`).
"""
from __future__ import annotations

import pickle
from pathlib import Path

import torch

from morphable.errors import InputError

__all__ = ["load_network"]


def load_network(path, build, missing: str, invalid: str):
    """``build(checkpoint dict) -> nn.Module`` on ``torch.load(path)``, in eval mode and frozen.

    Parameters
    ----------
    path : path of a ``torch.save`` file (loaded on the CPU, tensors only)
    build : callable(dict) -> nn.Module, constructing the network and loading its state
    missing, invalid : the error texts for an absent file and for a file ``build`` rejects
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {missing}")
    try:
        net = build(torch.load(path, map_location="cpu", weights_only=True))
    # a truncated or foreign file fails inside torch.load's unpickler
    except (KeyError, RuntimeError, EOFError, OSError, pickle.UnpicklingError) as e:
        raise InputError(f"{path}: {invalid} ({str(e).splitlines()[0]})") from None
    return net.eval().requires_grad_(False)
