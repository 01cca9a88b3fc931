"""The neural plugin's weights: where the committed files live (``neural/weights/``, see its
``MODEL_CARD.md``) and loading networks from checkpoint files with one-line errors that name
the file.

This module, not one named ``weights``, holds them because ``neural/weights/`` is the data
folder of the ``.pt`` files (package data): a ``neural/weights.py`` beside it would be a
second thing called ``neural.weights``. The inverter's and the aux networks' own loaders
stay beside their savers (:func:`neural.inverter.load_inverter`,
:func:`neural.auxnets.load_aux`) and take their default paths from here.
"""
from __future__ import annotations

import os
import pickle
from pathlib import Path

import torch

from morphable.errors import InputError

__all__ = ["WEIGHTS_DIR", "WEIGHTS_ENV", "GENERATOR_FILE", "default_generator_path",
           "default_no_norm_cycle_path", "default_inverter_path", "default_aux_path", "companion_path",
           "inverter_name",
           "load_network", "load_generator"]

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
"""The committed weights (tiny config, 64 px)."""
WEIGHTS_ENV = "MORPHABLE_GAR_WEIGHTS"
"""Environment variable naming the gar renderer's generator file."""
GENERATOR_FILE = WEIGHTS_DIR / "gar_tiny.pt"


def _committed(name: str) -> Path | None:
    p = WEIGHTS_DIR / name
    return p if p.is_file() else None


def default_generator_path() -> Path | None:
    """``$MORPHABLE_GAR_WEIGHTS`` if set, else ``neural/weights/gar_tiny.pt`` if present."""
    env = os.environ.get(WEIGHTS_ENV)
    if env:
        return Path(env)
    return _committed(GENERATOR_FILE.name)


def default_no_norm_cycle_path() -> Path | None:
    """``neural/weights/gar_tiny_no_norm_cycle.pt`` (the lambda_n = 0 generator) if committed."""
    return _committed("gar_tiny_no_norm_cycle.pt")


def default_inverter_path() -> Path | None:
    """``neural/weights/inverter_tiny.pt`` if committed, else None (pass ``inverter=`` to
    use another file, e.g. ``runs/inv/inverter.pt`` of :mod:`neural.train_inverter`)."""
    return _committed("inverter_tiny.pt")


def companion_path(generator_path, name: str) -> Path | None:
    """The file ``name`` (e.g. ``"inverter_tiny.pt"``) beside the generator file
    ``generator_path`` when present, else the committed one (or None): a weights folder holds
    a GAR together with the networks trained with it (``neural/weights/`` the synthetic set,
    ``neural/weights/real/`` the real-photo one, see the model card)."""
    if generator_path is not None:
        p = Path(generator_path).parent / name
        if p.is_file():
            return p
    return _committed(name)


def inverter_name(generator_path) -> str:
    """The file name of the inverter trained with the generator file ``generator_path``:
    ``inverter_<tag>.pt`` beside ``gar_<tag>.pt`` (``gar_64.pt`` -> ``inverter_64.pt``),
    ``inverter_tiny.pt`` for any other name (a run's ``generator.pt``)."""
    stem = Path(generator_path).stem if generator_path is not None else ""
    return f"inverter_{stem[4:]}.pt" if stem.startswith("gar_") else "inverter_tiny.pt"


def default_aux_path(name: str) -> Path:
    """Where the committed weights of aux net ``name`` live (``neural/weights/aux_N.pt``...)."""
    return WEIGHTS_DIR / f"aux_{name}.pt"


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


def load_generator(path, ema: bool = True):
    """A :class:`neural.gar.Generator` (eval mode) from ``generator.pt`` or ``checkpoint.pt``
    of :mod:`neural.train`; from a checkpoint, ``ema=False`` takes the raw generator instead
    of its moving average."""
    from .config import GARConfig
    from .gar import Generator

    def build(ckpt):
        G = Generator(GARConfig.from_dict(ckpt["config"]))
        G.load_state_dict(ckpt["G_ema"] if ema and "G_ema" in ckpt else ckpt["G"])
        return G

    return load_network(path, build, "generator weights not found", "not a GAR checkpoint")
