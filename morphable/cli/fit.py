"""``morphable fit``: fit the model to the landmarks of one or more images of a person.

Videos (``.mp4``, ``.mov``, ... :data:`morphable.video.VIDEO_SUFFIXES`) give ``--frames``
frames each, spread uniformly (default 5, the Florence protocol); frames without a face are
skipped and reported, and every frame, photo or video, shares one identity.

Landmarks come from ``--landmarks`` (iBUG ``.pts`` or menpo ``.ljson`` 68 points, or 478
face-mesh points in ``.npy``/``.json``, one file per image) or are detected
(``--landmark-detector``, ``--face-detector``; then fitted with a detector's error,
``DETECTED_MODEL_STD_MM``). Writes
the mesh (OBJ with UVs; the identity without expression, or ``--mesh expressive``), a JSON
report, a texture and overlays, all only once the fit has succeeded, and all or none.

``--refine photometric`` then fits the pictures' pixels (docs/photometric.md): one identity
for all frames, an albedo texture and each frame's light in closed form, a robust mask;
``--mesh`` chooses what the mesh holds (the same rule for one picture and for several).

The command line of :func:`morphable.pipeline.fit_images` and :meth:`ImageFit.write
<morphable.pipeline.ImageFit.write>`.
"""
from __future__ import annotations

from ..errors import InputError
from ..pipeline.outputs import MESH_KINDS
from .common import (add_fitting_arguments, add_loss_weight_argument, add_model_argument, model_from,
                     renderer_options)


def add_parser(sub):
    p = sub.add_parser("fit", help="fit identity, expression and pose to 2D landmarks of images")
    p.add_argument("images", nargs="+", metavar="IMAGE",
                   help="images or videos of one person (a video gives --frames frames)")
    p.add_argument("--frames", type=int, default=5, metavar="N",
                   help="frames sampled uniformly from each video (default 5, the Florence "
                        "protocol; all of a shorter video)")
    p.add_argument("--landmarks", nargs="+", metavar="PTS",
                   help="iBUG .pts/.ljson (68) or face-mesh .npy/.json (478) files, one per image "
                        "(default: detect, see --landmark-detector)")
    add_model_argument(p)
    add_fitting_arguments(p)
    faces = p.add_mutually_exclusive_group()
    faces.add_argument("--all-faces", action="store_true",
                       help="fit every face of one photo, each on its own, numbered from 0 left to "
                            "right: outputs NAME_K.* per face, one --overlay with every face and its number")
    faces.add_argument("--face", type=int, metavar="K",
                       help="fit face K of one photo (numbered from 0 left to right; default: the largest)")
    p.add_argument("--independent", action="store_true",
                   help="fit each image on its own; the mesh is the average identity")
    p.add_argument("--out-mesh", help="output mesh (.obj with UVs, .ply, .stl)")
    p.add_argument("--mesh", choices=MESH_KINDS, default="neutral",
                   help="what --out-mesh holds, for one image and for several alike: neutral (the "
                        "default: the identity without expression) or expressive (each frame's "
                        "face with its expression; several frames: NAME_0.obj, NAME_1.obj, ...)")
    p.add_argument("--report", help="output JSON report")
    p.add_argument("--out-texture", metavar="PNG",
                   help="output .png: the UV texture from the photos, or with --refine "
                        "photometric the recovered albedo (the model needs UVs); an .obj "
                        "--out-mesh then names it through an .mtl beside it")
    p.add_argument("--texture-size", type=int, default=512, help="texels per side (default 512)")
    p.add_argument("--texture-source", choices=("albedo", "photo"), default="albedo",
                   help="what --out-texture holds after --refine photometric: the recovered albedo "
                        "(default) or the photos' colours, shading included (without the "
                        "photometric refinement always the photos' colours)")
    p.add_argument("--overlay", help="output .png/.jpg: the image with the fitted mesh and landmarks "
                                     "(several images: NAME_0.png, NAME_1.png, ...)")
    p.add_argument("--overlay-style", choices=("shaded", "wireframe", "none"), default="shaded",
                   help="how --overlay draws the mesh (default shaded)")
    p.add_argument("--overlay-crop", type=float, metavar="MARGIN",
                   help="cut --overlay to the face, widened by MARGIN times its size (e.g. 0.2) "
                        "(default: the whole image)")
    p.add_argument("--overlay-mask", action="store_true",
                   help="tint red on --overlay the face pixels the photometric mask weighs "
                        "under 0.5 (needs --refine)")
    p.add_argument("--refine", choices=("photometric", "classical", "gar"),
                   help="then fit the pixels, all frames with one identity (needs torch, the "
                        "neural extra): photometric (albedo texture and light in closed form, "
                        "docs/photometric.md; classical is the same) or gar (the neural renderer: "
                        "the generator of $MORPHABLE_GAR_WEIGHTS, default the synthetic "
                        "neural/gar/weights/gar_tiny.pt; see neural/gar/README.md) (default: no "
                        "refinement)")
    p.add_argument("--steps", type=int, default=100, help="--refine Adam steps (default 100)")
    add_loss_weight_argument(p, what="--refine")
    p.add_argument("--inverter", metavar="PT", help="gar: inverter V weights for the latent "
                                                    "(default: the one beside the generator's weights, "
                                                    "e.g. inverter_tiny.pt beside gar_tiny.pt, else "
                                                    "neural/gar/weights/inverter_tiny.pt)")
    p.add_argument("--refine-render", metavar="PNG",
                   help="output .png: the face crop next to the refined render (first image)")
    return p


def run(args):
    from ..pipeline import check_output_paths, fit_images
    from ..refinement import parse_loss_weights

    # every output checked first: either every output is written or none
    check_output_paths(mesh=args.out_mesh, report=args.report, texture=args.out_texture,
                       overlay=args.overlay, refine_render=args.refine_render)
    model = model_from(args)
    if args.out_texture:
        if model.uv is None:
            raise InputError(f"{args.model}: the model has no UV coordinates, so --out-texture "
                             "cannot be written")
        if not 8 <= args.texture_size <= 8192:
            raise InputError(f"--texture-size must be 8..8192 texels, got {args.texture_size}")
    if args.landmarks and len(args.landmarks) != len(args.images):
        raise InputError(f"--landmarks: {len(args.landmarks)} files for {len(args.images)} images")
    if args.n_iterations < 0:
        raise InputError(f"--n-iterations must be >= 0, got {args.n_iterations}")
    if args.frames < 1:
        raise InputError(f"--frames must be >= 1, got {args.frames}")
    if args.steps < 0:
        raise InputError(f"--steps must be >= 0, got {args.steps}")
    if args.refine_render and not args.refine:
        raise InputError("--refine-render needs --refine")
    if args.overlay_mask and not (args.refine and args.overlay):
        raise InputError("--overlay-mask needs --refine and --overlay")
    if args.refine in ("photometric", "classical") and model.uv is None:
        raise InputError(f"{args.model}: the model has no UV coordinates, so --refine "
                         f"{args.refine} cannot hold an albedo texture")
    if args.loss_weight and not args.refine:
        raise InputError("--loss-weight needs --refine")
    weights = parse_loss_weights(args.loss_weight, "--loss-weight")
    refine_options = None
    if args.refine:
        refine_options = {"steps": args.steps, "weights": weights,
                          "renderer_options": renderer_options(args.inverter)}
    if args.face is not None and args.face < 0:
        raise InputError(f"--face must be >= 0, got {args.face}")
    if (args.all_faces or args.face is not None) and (len(args.images) != 1 or args.landmarks):
        raise InputError(f"{'--all-faces' if args.all_faces else '--face'}: for one photo whose faces "
                         "are detected (no --landmarks)")
    result = fit_images(args.images, args.landmarks, model=model, refine=args.refine,
                        refine_options=refine_options, camera=args.camera, focal_px=args.focal_px,
                        n_iterations=args.n_iterations, robust=args.robust,
                        shared_identity=not args.independent,
                        landmark_detector=args.landmark_detector, face_detector=args.face_detector,
                        landmark_std_px=args.landmark_std, video_frames=args.frames,
                        face=args.face, all_faces=args.all_faces)
    if args.all_faces:
        return _write_all_faces(args, result)
    result.write(mesh=args.out_mesh, report=args.report, texture=args.out_texture, overlay=args.overlay,
                 texture_size=args.texture_size,
                 overlay_style=None if args.overlay_style == "none" else args.overlay_style,
                 overlay_crop=args.overlay_crop, refine_render=args.refine_render,
                 mesh_kind=args.mesh, overlay_mask=args.overlay_mask,
                 albedo=args.texture_source == "albedo")
    report, res = result.report, result.fit
    if report.get("faces_seen", 1) > 1:
        n = report["faces_seen"] - 1
        print(f"{args.images[0]}: {n} other face{'s' * (n > 1)} seen, the largest fitted "
              "(--all-faces fits every face, --face K one)")
    for picture, run in zip(result.pictures, report.get("refine", [])):
        if run["fallback"]:
            print(f"{picture.label}: refine {args.refine}: the mask keeps {100 * run['mask_coverage']:.1f} % "
                  "of the face; kept the landmark fit")
            continue
        print(f"{picture.label}: refine {args.refine}: photometric loss {run['photometric_loss'][0]:.4f} -> "
              f"{run['photometric_loss'][-1]:.4f}, residual {run['photometric_residual']:.3f}, "
              f"mask {100 * run['mask_coverage']:.0f} % of the face; {run['runtime_s']:.1f} s "
              f"for {run['frames_together']} frame(s)")
    for f in report.get("frames_skipped", []):
        print(f"{f['image']} ({f['time_s']:.3f} s): skipped, {f['reason']}")
    for f in report["frames"]:
        print(f"{f['image']}: landmark RMSE {f['landmark_rmse_px']:.2f} px, yaw {f['yaw_deg']:.1f}, "
              f"pitch {f['pitch_deg']:.1f}, roll {f['roll_deg']:.1f} deg")
    print(f"{res.iterations} iterations, {res.runtime_ms:.1f} ms"
          + (f"; wrote {args.out_mesh}" if args.out_mesh else "")
          + (f" {args.report}" if args.report else "")
          + (f" {args.out_texture}" if args.out_texture else ""))
    return 0


def _numbered(path, k: int):
    """``out/fit.obj`` -> ``out/fit_K.obj`` (None stays None)."""
    from pathlib import Path

    if not path:
        return None
    p = Path(path)
    return str(p.with_name(f"{p.stem}_{k}{p.suffix}"))


def _write_all_faces(args, results) -> int:
    """``--all-faces``: each face's files as NAME_K.*, one overlay of every face with its
    number; all or nothing."""
    from pathlib import Path

    import numpy as np

    from ..io.atomic import atomic_path
    from ..overlay import draw_overlay, label_faces

    written = []
    try:
        for k, result in enumerate(results):
            written += result.write(mesh=_numbered(args.out_mesh, k), report=_numbered(args.report, k),
                                    texture=_numbered(args.out_texture, k), texture_size=args.texture_size,
                                    refine_render=_numbered(args.refine_render, k), mesh_kind=args.mesh,
                                    albedo=args.texture_source == "albedo")
        if args.overlay:
            from PIL import Image

            image = results[0].pictures[0].pixels()
            style = None if args.overlay_style == "none" else args.overlay_style
            for result in results:
                image = draw_overlay(image, result.fit, 0, mesh=style)
            boxes = [r.report["face"]["box_px"] for r in results]
            image = label_faces(image, boxes, [str(r.report["face"]["index"]) for r in results])
            if args.overlay_crop is not None:
                b = np.array(boxes)
                lo, hi = b[:, :2].min(0), b[:, 2:].max(0)
                pad = args.overlay_crop * (hi - lo)
                x0, y0 = np.maximum(0, np.floor(lo - pad)).astype(int)
                x1, y1 = np.ceil(hi + pad).astype(int)
                image = image[y0:y1, x0:x1]
            with atomic_path(args.overlay) as tmp:
                Image.fromarray(image).save(tmp, format="JPEG" if Path(args.overlay).suffix.lower() in
                                            (".jpg", ".jpeg") else "PNG")
            written.append(Path(args.overlay))
    except BaseException:
        for p in written:
            Path(p).unlink(missing_ok=True)
        raise
    for result in results:
        f, face = result.report["frames"][0], result.report["face"]
        print(f"{args.images[0]} face {face['index']} of {face['faces_found']}: landmark RMSE "
              f"{f['landmark_rmse_px']:.2f} px, yaw {f['yaw_deg']:.1f}, pitch {f['pitch_deg']:.1f}, "
              f"roll {f['roll_deg']:.1f} deg")
    print(f"{len(results)} face{'s' * (len(results) > 1)} fitted"
          + (f"; wrote {' '.join(str(p) for p in written)}" if written else ""))
    return 0
