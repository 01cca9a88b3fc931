"""The landmark network exported to ONNX, for onnxruntime (:mod:`neural.landmarks.runtime`):
``python -m neural.landmarks.export [--weights FILE.pt] [--out FILE.onnx] [--fp16]``
(``make landmark-onnx`` for the committed weights).

The graph takes ``crops`` (B, 3, R, R) float32 in [-1, 1] (any B) and gives ``points``,
``log_sigma`` and ``score`` as :class:`neural.landmarks.network.LandmarkNet` does; its metadata
holds the network's config, the weights file's ``meta`` and the weights file's SHA-256
(:data:`neural.landmarks.runtime.METADATA`). ``--fp16`` stores the weights as float16 (half the
file; each is cast back to float32 once, when onnxruntime loads the graph, so it runs as
fast). After writing, the graph is run by onnxruntime on random crops beside torch and the
largest differences printed.

Needs torch, ``onnx`` and ``onnxscript`` (the ``dev`` extra: torch's exporter); running the
graph needs only onnxruntime (the ``neural`` extra).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from morphable.errors import InputError
from morphable.io.registry import sha256

from .runtime import METADATA, OUTPUTS, onnx_path

__all__ = ["OPSET", "export_onnx", "weights_to_fp16", "compare", "main"]

OPSET = 18


def export_onnx(weights, out=None, fp16: bool = False) -> Path:
    """Export the weights file ``weights`` (:func:`neural.landmarks.network.save_landmark_net`'s)
    to the ONNX graph ``out`` (default: beside it, :func:`neural.landmarks.runtime.onnx_path`),
    written atomically -> ``out``."""
    import onnx
    import torch

    from morphable.io.atomic import atomic_path

    from .network import load_landmark_net

    weights = Path(weights)
    out = onnx_path(weights) if out is None else Path(out)
    net = load_landmark_net(weights)

    class Outputs(torch.nn.Module):
        """The network's dict as the graph's three outputs, in :data:`OUTPUTS` order."""

        def __init__(self):
            super().__init__()
            self.net = net

        def forward(self, crops):
            found = self.net(crops)
            return tuple(found[k] for k in OUTPUTS)

    R = net.config.resolution
    program = torch.onnx.export(Outputs().eval(), (torch.zeros(2, 3, R, R),), dynamo=True,
                                input_names=["crops"], output_names=list(OUTPUTS), opset_version=OPSET,
                                dynamic_shapes={"crops": {0: torch.export.Dim("batch")}}, verbose=False)
    model = program.model_proto
    if fp16:
        weights_to_fp16(model)
    meta = {METADATA["config"]: json.dumps(net.config.to_dict()),
            METADATA["meta"]: json.dumps(net.meta, default=str),
            METADATA["source"]: sha256(weights)}
    onnx.helper.set_model_props(model, meta)
    onnx.checker.check_model(model)
    with atomic_path(out) as tmp:
        onnx.save_model(model, str(tmp))
    return out


def weights_to_fp16(model) -> None:
    """The float32 initializers of an ONNX ``model`` (a ModelProto, changed in place) stored as
    float16, each followed by a Cast back to float32 under its old name: the graph computes
    in float32 on weights rounded to float16."""
    from onnx import TensorProto, helper, numpy_helper

    graph = model.graph
    casts, kept = [], []
    for init in graph.initializer:
        if init.data_type != TensorProto.FLOAT:
            kept.append(init)
            continue
        half = numpy_helper.from_array(numpy_helper.to_array(init).astype(np.float16), init.name + "_fp16")
        kept.append(half)
        casts.append(helper.make_node("Cast", [half.name], [init.name], to=TensorProto.FLOAT))
    del graph.initializer[:]
    graph.initializer.extend(kept)
    nodes = casts + list(graph.node)
    del graph.node[:]
    graph.node.extend(nodes)


def compare(weights, graph, n: int = 16, seed: int = 0) -> dict:
    """Largest differences of the ONNX ``graph`` on onnxruntime from the torch network of
    ``weights`` on ``n`` random crops: ``points`` (crop-normalised), ``log_sigma``, ``score``."""
    from .runtime import OnnxNetwork, TorchNetwork

    torch_net, ort_net = TorchNetwork(weights), OnnxNetwork(graph)
    R = torch_net.resolution
    x = np.random.default_rng(seed).uniform(-1, 1, (n, 3, R, R)).astype(np.float32)
    a, b = torch_net(x), ort_net(x)
    return {k: float(np.abs(a[k] - b[k]).max()) for k in OUTPUTS}


def main(argv=None) -> int:
    from .detector import WEIGHTS_FILE

    p = argparse.ArgumentParser(prog="python -m neural.landmarks.export", description=__doc__.split("\n\n")[0])
    p.add_argument("--weights", type=Path, default=WEIGHTS_FILE, help="the .pt file (default: the committed weights)")
    p.add_argument("--out", type=Path, help="the .onnx file (default: beside the weights)")
    p.add_argument("--fp16", action="store_true", help="store the weights as float16")
    a = p.parse_args(argv)
    try:
        out = export_onnx(a.weights, a.out, fp16=a.fp16)
    except InputError as e:
        print(f"error: {e}")
        return 2
    diff = compare(a.weights, out)
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB); onnxruntime - torch on 16 random crops, "
          "largest |difference|: " + ", ".join(f"{k} {v:.2g}" for k, v in diff.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
