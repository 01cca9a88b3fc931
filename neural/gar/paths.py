"""Where the GAR's committed weights live (``neural/gar/weights/``, described in its
``MODEL_CARD.md``): the generator, the lambda_n = 0 generator, the inverter V and the
auxiliary networks, and the files trained together with a given generator.

A module of paths rather than one named ``weights``: ``neural/gar/weights/`` is the data
folder of the ``.pt`` files (package data). The loaders stay beside their networks
(:func:`neural.gar.networks.load_generator`, :func:`neural.gar.inverter.load_inverter`,
:func:`neural.gar.auxnets.load_aux`) and take their default paths from here.
"""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["WEIGHTS_DIR", "WEIGHTS_ENV", "GENERATOR_FILE", "default_generator_path",
           "default_no_norm_cycle_path", "default_inverter_path", "default_aux_path", "companion_path",
           "inverter_name"]

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
"""The committed weights (tiny config, 64 px)."""
WEIGHTS_ENV = "MORPHABLE_GAR_WEIGHTS"
"""Environment variable naming the gar renderer's generator file."""
GENERATOR_FILE = WEIGHTS_DIR / "gar_tiny.pt"


def _committed(name: str) -> Path | None:
    p = WEIGHTS_DIR / name
    return p if p.is_file() else None


def default_generator_path() -> Path | None:
    """``$MORPHABLE_GAR_WEIGHTS`` if set, else ``neural/gar/weights/gar_tiny.pt`` if present."""
    env = os.environ.get(WEIGHTS_ENV)
    if env:
        return Path(env)
    return _committed(GENERATOR_FILE.name)


def default_no_norm_cycle_path() -> Path | None:
    """``neural/gar/weights/gar_tiny_no_norm_cycle.pt`` (the lambda_n = 0 generator) if committed."""
    return _committed("gar_tiny_no_norm_cycle.pt")


def default_inverter_path() -> Path | None:
    """``neural/gar/weights/inverter_tiny.pt`` if committed, else None (pass ``inverter=`` to
    use another file, e.g. ``runs/inv/inverter.pt`` of :mod:`neural.gar.train_inverter`)."""
    return _committed("inverter_tiny.pt")


def companion_path(generator_path, name: str) -> Path | None:
    """The file ``name`` (e.g. ``"inverter_tiny.pt"``) beside the generator file
    ``generator_path`` when present, else the committed one (or None): a weights folder holds
    a GAR together with the networks trained with it (``neural/gar/weights/`` the synthetic set,
    ``neural/gar/weights/real/`` the real-photo one, see the model card)."""
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
    """Where the committed weights of aux net ``name`` live (``neural/gar/weights/aux_N.pt``...)."""
    return WEIGHTS_DIR / f"aux_{name}.pt"
