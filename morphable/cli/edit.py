"""``morphable edit``: reconstruct a face (landmark fit + renderer inversion) and re-render it
under another pose or expression with the recovered appearance.

``morphable edit IMAGE --yaw 20 --expression happiness=0.8 --out edited.png`` writes the face
crop, the reconstruction and the edit side by side (``--only-edit``: the edit alone), at the
renderer's resolution times ``--zoom``.
"""
from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from .common import (add_detector_arguments, add_loss_weight_argument, add_model_argument, model_from,
                     parse_weights, renderer_options)


def add_parser(sub):
    p = sub.add_parser("edit", help="change the pose/expression of a face in an image "
                                    "(neural renderer inversion)")
    p.add_argument("image", metavar="IMAGE", help="a photo of one face")
    p.add_argument("--landmarks", metavar="PTS", help="iBUG .pts/.ljson (68) or face-mesh .npy/.json "
                                                      "(478) (default: detect, see --landmark-detector)")
    add_detector_arguments(p)
    add_model_argument(p)
    p.add_argument("--renderer", choices=("gar", "classical"), default="gar",
                   help="the renderer inverted: gar (the neural plugin's generator: $MORPHABLE_GAR_WEIGHTS, "
                        "default neural/gar/weights/gar_tiny.pt) or classical "
                        "(Lambertian, uniform albedo, spherical-harmonics light) (default gar)")
    p.add_argument("--steps", type=int, default=100, help="refinement Adam steps (default 100)")
    add_loss_weight_argument(p)
    p.add_argument("--inverter", metavar="PT", help="gar: inverter V weights for the latent "
                                                    "(default: the one beside the generator's weights, "
                                                    "e.g. inverter_tiny.pt beside gar_tiny.pt, else "
                                                    "neural/gar/weights/inverter_tiny.pt)")
    p.add_argument("--yaw", type=float, help="new yaw, degrees (default: the recovered one)")
    p.add_argument("--pitch", type=float, help="new pitch, degrees (default: the recovered one)")
    p.add_argument("--roll", type=float, help="new roll, degrees (default: the recovered one)")
    p.add_argument("--expression", nargs="*", default=[], metavar="NAME=WEIGHT",
                   help="expression coefficients to set, e.g. happiness=0.8 (default: the recovered ones)")
    p.add_argument("--out", required=True, help="output .png")
    p.add_argument("--only-edit", action="store_true", help="write only the edited render")
    p.add_argument("--zoom", type=int, default=4, help="nearest-neighbour enlargement (default 4)")
    p.add_argument("--report", help="output JSON report of the reconstruction")
    return p


def run(args):
    import json

    import numpy as np

    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise InputError(f"{out}: --out must be a .png file")
    for o in (args.out, args.report):
        if o and not Path(o).resolve().parent.is_dir():
            raise InputError(f"{o}: folder {Path(o).resolve().parent} does not exist")
    if args.steps < 0 or args.zoom < 1:
        raise InputError("--steps must be >= 0 and --zoom >= 1")
    model = model_from(args)
    expression = {}
    for item in args.expression:
        w = parse_weights(model, [item])          # validates the name and the number
        name = item.partition("=")[0]
        expression[name] = w[model.expression_index(name)]
    from ..io.atomic import atomic_path
    from ..pipeline import fit_images
    from ..raster import save_image_png
    from ..refinement import edit, parse_loss_weights

    weights = parse_loss_weights(args.loss_weight, "--loss-weight")
    options = renderer_options(args.inverter, what="edit")

    result = fit_images(args.image, args.landmarks, model=model, refine=args.renderer,
                        refine_options={"steps": args.steps, "weights": weights, "renderer_options": options},
                        landmark_detector=args.landmark_detector, face_detector=args.face_detector)
    report, state = result.report["refine"][0], result.refinements[0]
    edited = edit(state, yaw=args.yaw, pitch=args.pitch, roll=args.roll, expression=expression)
    img = edited if args.only_edit else np.concatenate([state.target, state.rendered, edited], 1)
    img = img.repeat(args.zoom, 0).repeat(args.zoom, 1)
    save_image_png(out, img)
    if args.report:
        report["edit"] = {"yaw": args.yaw, "pitch": args.pitch, "roll": args.roll,
                          "expression": expression}
        with atomic_path(args.report) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=2))
    print(f"{args.image}: {args.renderer} reconstruction, photometric loss "
          f"{report['photometric_loss'][0]:.4f} -> {report['photometric_loss'][-1]:.4f} in "
          f"{report['runtime_s']:.1f} s; wrote {out}")
    return 0
