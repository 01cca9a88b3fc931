"""The frozen auxiliary networks of the GAR losses and their loader.

========  ==============================================  ==================================
name      input (B, 3, H, W) image in [-1, 1] ->           used by
========  ==============================================  ==================================
``"N"``   unit normals (B, 3, H, W), camera frame          L_n (normal consistency)
``"P"``   face-mask probability (B, 1, H, W)               L_n (the mask)
``"L"``   68 heatmap logits (B, 68, H, W);                  L_ldmk
          ``.landmarks(image)`` -> (B, 68, 2) pixels
``"R"``   identity embedding (B, D)                        L_id, fid_aux
========  ==============================================  ==================================

No pretrained weights can be downloaded here, so small versions (:mod:`neural.gar.auxnets.nets`) are
trained on synthetic renders with exact labels (:mod:`neural.gar.auxnets.train`). A stronger model
with the same interface replaces one through ``load_aux(name, weights=...)``: a checkpoint
of our architecture, a TorchScript file, or an ``nn.Module``.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import torch
from torch import nn

from morphable.errors import InputError

from ..paths import default_aux_path
from .nets import NETS, soft_argmax

__all__ = ["load_aux", "save_aux", "build_aux", "NAMES"]

NAMES = tuple(NETS)


def build_aux(name: str, width: int = 16) -> nn.Module:
    """A fresh (untrained) aux network of our architecture."""
    if name not in NETS:
        raise InputError(f"unknown aux network {name!r}; choose from {', '.join(NETS)}")
    return NETS[name](width=width)


def save_aux(net: nn.Module, name: str, path, width: int, **meta) -> Path:
    """Write ``{"name", "width", "state_dict", "meta"}`` to ``path`` atomically."""
    from morphable.io.atomic import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"name": name, "width": width, "state_dict": net.state_dict(),
                    "meta": meta}, tmp)
    return path


class _WithLandmarks(nn.Module):
    """Gives a user heatmap network (B, 68, h, w) the ``landmarks`` method in input pixels."""

    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, image):
        return self.net(image)

    def landmarks(self, image):
        heat = self(image)
        scale = image.shape[-1] / heat.shape[-1]
        # heatmap pixel centres map to image pixel centres: x_img = (x + 0.5) * s - 0.5
        return (soft_argmax(heat) + 0.5) * scale - 0.5


def _from_file(name: str, path: Path) -> nn.Module:
    if not path.is_file():
        raise InputError(f"{path}: aux weights file not found")
    try:
        with warnings.catch_warnings():
            # torch.load hands TorchScript archives to torch.jit.load with a warning
            warnings.simplefilter("ignore")
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:
        ckpt = None
    if isinstance(ckpt, nn.Module):
        return ckpt
    if isinstance(ckpt, dict):
        state = ckpt.get("state_dict", ckpt)
        if ckpt.get("name", name) != name:
            raise InputError(f"{path}: holds aux network {ckpt['name']!r}, not {name!r}")
        net = build_aux(name, int(ckpt.get("width", 16)))
        try:
            net.load_state_dict(state)
        except RuntimeError as e:
            first = str(e).strip().splitlines()[0]
            raise InputError(f"{path}: weights do not fit aux network {name!r} ({first})") from None
        net.meta = ckpt.get("meta", {})
        return net
    try:
        return torch.jit.load(str(path), map_location="cpu")
    except Exception:
        raise InputError(f"{path}: neither a checkpoint nor a TorchScript module") from None


def _check_interface(name: str, net: nn.Module, where: str, resolution: int):
    x = torch.zeros(1, 3, resolution, resolution)
    with torch.no_grad():
        y = net(x)
    expected = {"N": (1, 3, resolution, resolution), "P": (1, 1, resolution, resolution)}
    ok = (tuple(y.shape) == expected[name] if name in expected
          else (y.dim() == 4 and y.shape[:2] == (1, 68)) if name == "L"
          else y.dim() == 2 and y.shape[0] == 1)
    if not ok:
        raise InputError(f"{where}: aux network {name!r} returns shape {tuple(y.shape)} for a "
                         f"(1, 3, {resolution}, {resolution}) image; see neural.gar.auxnets for the interface")


def load_aux(name: str, weights=None, pretrained: bool = True, width: int = 16,
             resolution: int = 64, device="cpu") -> nn.Module:
    """A frozen (eval mode, no gradients) auxiliary network.

    Parameters
    ----------
    name : "N", "P", "L" or "R"
    weights : None, path or nn.Module
        None: the committed weights ``neural/gar/weights/aux_<name>.pt``. A path: a checkpoint
        written by :func:`save_aux` or a TorchScript file of a stronger model with the same
        interface. An ``nn.Module``: used as is.
    pretrained : bool
        False returns a fresh network of ``width`` (for training), still frozen.
    resolution : int
        Image size used to check the interface of user-supplied networks.

    Raises
    ------
    InputError
        Unknown name, missing or unreadable weights, or a network whose outputs do not
        match the interface.

    A network read from a checkpoint of :func:`save_aux` carries its stored ``meta`` (training
    settings, validation metrics) as ``net.meta``.

    Examples
    --------
    >>> net = load_aux("P", pretrained=False)
    >>> any(p.requires_grad for p in net.parameters()), net.training
    (False, False)
    """
    if name not in NETS:
        raise InputError(f"unknown aux network {name!r}; choose from {', '.join(NETS)}")
    if isinstance(weights, nn.Module):
        net, where = weights, f"aux network {name!r}"
    elif weights is not None:
        net, where = _from_file(name, Path(weights)), str(weights)
    elif not pretrained:
        net, where = build_aux(name, width), f"aux network {name!r}"
    else:
        path = default_aux_path(name)
        if not path.is_file():
            raise InputError(f"{path}: no trained weights for aux network {name!r}; train them "
                             f"with `python -m neural.gar.auxnets.train` or pass weights=")
        net, where = _from_file(name, path), str(path)
    if name == "L" and not hasattr(net, "landmarks"):
        meta = getattr(net, "meta", None)
        net = _WithLandmarks(net)
        if meta is not None:
            net.meta = meta
    net = net.to(device).eval().requires_grad_(False)
    _check_interface(name, net, where, resolution)
    return net
