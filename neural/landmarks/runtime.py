"""The landmark network's forward pass on numpy crops, through onnxruntime or torch.

:func:`load` gives a callable ``network(x)``: crops x (B, 3, R, R) float32 in [-1, 1] -> dict
of ``points`` (B, P, 2) crop-normalised, ``log_sigma`` (B, P) log crop px, ``score`` (B,) face
logit, float32 numpy arrays, with ``resolution`` (R) and ``n_points`` (P) beside it:

- ``"onnxruntime"``: the network exported to ONNX (``python -m neural.landmarks.export``: the
  file of the same name with the suffix ``.onnx`` beside the weights, e.g. the committed
  ``neural/landmarks/weights/landmarks.onnx``), run by onnxruntime on :data:`THREADS` thread;
  the graph names the weights file it came from by its SHA-256, so that weights changed after
  the export are not silently read by the old graph. Loads in about a tenth of torch's time
  (docs/landmark_net.md, "Without torch");
- ``"torch"``: the weights file itself through :mod:`neural.landmarks.network`;
- ``"auto"``: onnxruntime where it is installed and the graph is there, else torch.

Nothing here imports torch or onnxruntime until :func:`load` runs the one chosen.
"""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np

from morphable.errors import InputError
from morphable.io.registry import sha256

__all__ = ["BACKENDS", "THREADS", "METADATA", "OUTPUTS", "onnx_path", "choose_backend",
           "load", "OnnxNetwork", "TorchNetwork"]

BACKENDS = ("auto", "onnxruntime", "torch")
THREADS = 1
"""onnxruntime's intra-op threads: one, as :mod:`morphable.threads` holds BLAS and torch at one
for the small products of a fit (spinning pool threads fight whatever else runs); the one
thread's speed is the benchmark's (docs/landmark_net.md)."""
METADATA = {"config": "morphable.landmark_config", "meta": "morphable.landmark_meta",
            "source": "morphable.source_sha256"}
"""The keys of the ONNX graph's metadata: the network's :class:`~neural.landmarks.network.LandmarkConfig`
(JSON), the weights file's ``meta`` (JSON) and that file's SHA-256."""
OUTPUTS = ("points", "log_sigma", "score")


def onnx_path(weights) -> Path:
    """The ONNX graph of a weights file: ``weights`` itself when it ends in ``.onnx``, else the
    file of the same name with that suffix beside it."""
    weights = Path(weights)
    return weights if weights.suffix == ".onnx" else weights.with_suffix(".onnx")


def _installed(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def choose_backend(weights, backend: str = "auto") -> str:
    """The backend that :func:`load` runs for ``weights`` (a path), imports nothing:
    ``"onnxruntime"`` or ``"torch"``. InputError when ``backend`` is unknown or cannot run
    here (the message says what is missing)."""
    weights, graph = Path(weights), onnx_path(weights)
    if backend not in BACKENDS:
        raise InputError(f"landmark network backend: choose from {', '.join(BACKENDS)}, got {backend!r}")
    ort_ok, torch_ok = _installed("onnxruntime"), _installed("torch")
    if backend in ("auto", "onnxruntime") and ort_ok and graph.is_file():
        return "onnxruntime"
    if backend in ("auto", "torch") and torch_ok and weights.suffix != ".onnx":
        if not weights.is_file():
            raise InputError(f"{weights}: landmark network weights not found")
        return "torch"
    if backend == "onnxruntime" or weights.suffix == ".onnx":
        why = "onnxruntime is not installed" if not ort_ok else f"{graph}: no such ONNX graph"
    elif backend == "torch":
        why = "torch is not installed"
    else:
        why = (f"neither onnxruntime with {graph.name} beside the weights nor torch is installed"
               if not torch_ok else f"{weights}: landmark network weights not found")
    raise InputError(f"the landmark network cannot run: {why}")


def load(weights, backend: str = "auto"):
    """The network of ``weights`` (a ``.pt`` file of :func:`neural.landmarks.network.save_landmark_net`
    or its exported ``.onnx`` graph) on ``backend`` (:func:`choose_backend`) -> an
    :class:`OnnxNetwork` or :class:`TorchNetwork`. InputError naming the file when it is
    missing, not a landmark network, or (ONNX) exported from other weights than those beside it."""
    weights = Path(weights)
    if choose_backend(weights, backend) == "onnxruntime":
        source = weights if weights.suffix != ".onnx" and weights.is_file() else None
        return OnnxNetwork(onnx_path(weights), source=source)
    return TorchNetwork(weights)


class OnnxNetwork:
    """The exported graph on onnxruntime (see the module's docstring).

    path : the ``.onnx`` file; source : the weights file it must have been exported from
    (checked by SHA-256), or None."""

    backend = "onnxruntime"

    def __init__(self, path, source=None):
        import onnxruntime as ort

        self.path = Path(path)
        options = ort.SessionOptions()
        options.intra_op_num_threads = THREADS
        options.inter_op_num_threads = 1
        options.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
            found = self.session.get_modelmeta().custom_metadata_map
            config = json.loads(found[METADATA["config"]])
        except Exception as e:      # onnxruntime's own errors for a foreign or broken file
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise InputError(f"{self.path}: not an exported landmark network ({first[:200]})") from None
        if source is not None and found.get(METADATA["source"]) != sha256(source):
            raise InputError(f"{self.path} was exported from other weights than {source}: export "
                             f"again (python -m neural.landmarks.export --weights {source})")
        self.config = config
        self.meta = json.loads(found.get(METADATA["meta"], "{}"))
        self.resolution, self.n_points = int(config["resolution"]), int(config["n_points"])
        self.input = self.session.get_inputs()[0].name

    def __call__(self, x: np.ndarray) -> dict:
        out = self.session.run(list(OUTPUTS), {self.input: np.ascontiguousarray(x, dtype=np.float32)})
        return dict(zip(OUTPUTS, out))


class TorchNetwork:
    """The weights file on torch (:func:`neural.landmarks.network.load_landmark_net`)."""

    backend = "torch"

    def __init__(self, path):
        from .network import load_landmark_net

        self.path = Path(path)
        self.net = load_landmark_net(path)
        self.config = self.net.config.to_dict()
        self.meta = self.net.meta
        self.resolution, self.n_points = self.net.config.resolution, self.net.config.n_points

    def __call__(self, x: np.ndarray) -> dict:
        import torch

        with torch.inference_mode():
            out = self.net(torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32)))
        return {k: out[k].numpy() for k in OUTPUTS}
