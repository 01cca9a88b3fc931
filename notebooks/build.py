"""Write the example notebooks (outputs stripped) from the cells below.

    .venv/bin/python notebooks/build.py        # rewrites notebooks/*.ipynb

The notebooks are the source users open; this script keeps them reviewable as plain Python
and guarantees that the committed files carry no outputs. ``tests/test_notebooks.py`` runs
them top to bottom and checks that they match this script.
"""
from __future__ import annotations

import sys
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent

SETUP = '''\
import importlib.util
import os
import sys
from pathlib import Path

import numpy as np
import matplotlib.pyplot as plt

REPO = Path.cwd().resolve().parent  # notebooks/ -> the repository
# the shared data beside the repository (override with MORPHABLE_SHARED_DATA)
DATA = Path(os.environ.get("MORPHABLE_SHARED_DATA", REPO.parent / "shared" / "data"))
OUT = Path(os.environ.get("MORPHABLE_NOTEBOOK_OUT", REPO / "out" / "notebooks"))
OUT.mkdir(parents=True, exist_ok=True)
if importlib.util.find_spec("evaluation") is None:  # evaluation/ and neural/ sit beside morphable/
    sys.path.insert(0, str(REPO))
print("data:", DATA, "| outputs:", OUT)'''


def fit_a_photo():
    return [
        new_markdown_cell("""\
# 01 — Fit a photo

Detect the 68 iBUG landmarks of a face with dlib, fit the Surrey Face Model (identity,
expression, pose) to them, draw the fit over the photo, and export the mesh. The command
line does the same in one step:

```
morphable fit ../shared/data/images/image_0010.png --out-mesh fit.obj --report fit.json --overlay overlay.png
```"""),
        new_code_cell(SETUP),
        new_markdown_cell("## The photo and its landmarks\n\n"
                          "`morphable.detection.detect_ibug68`: the face mesh (mediapipe, 478 points, here"
                          " mapped to the 68 iBUG points), or dlib's 68-point detector where mediapipe is"
                          " not installed; the photo also comes with hand-annotated landmarks (`.pts`) to"
                          " compare with."),
        new_code_cell('''\
from PIL import Image

from morphable.detection import detect_ibug68
from morphable.io.landmark_files import read_pts

photo_path = DATA / "images" / "image_0010.png"
photo = np.asarray(Image.open(photo_path).convert("RGB"))
detected = detect_ibug68(photo)  # (68, 2) pixels, x right, y down
annotated = read_pts(photo_path.with_suffix(".pts"))
gap = np.linalg.norm(detected - annotated, axis=1)
print(f"{photo.shape[1]}x{photo.shape[0]} px; detected vs annotated: median {np.median(gap):.1f} px, "
      f"max {gap.max():.1f} px")
assert np.median(gap) < 15'''),
        new_markdown_cell("## Fit\n\nIdentity and expression coefficients are in standard deviations;"
                          " the camera is scaled orthographic (`camera=\"perspective\"` is the other choice)."),
        new_code_cell('''\
from morphable import load_model
from morphable.fitting import fit_landmarks
from morphable.fitting.noise import DETECTED_MODEL_STD_MM

model = load_model("sfm")
H, W = photo.shape[:2]
# a detector's errors are face-shaped: fit its points with its larger per-frame error
fit = fit_landmarks(model, detected[None], [[W, H]], model_std_mm=DETECTED_MODEL_STD_MM)
yaw, pitch, roll = fit.euler_deg[0]
print(f"landmark RMSE {fit.landmark_rmse_px[0]:.2f} px, yaw {yaw:.1f}, pitch {pitch:.1f}, "
      f"roll {roll:.1f} deg, {fit.runtime_ms:.0f} ms")
top = np.argsort(-fit.expression[0])[:3]
print("largest expression weights:", ", ".join(f"{model.expression_names[i]} {fit.expression[0, i]:.2f}"
                                               for i in top))
assert fit.landmark_rmse_px[0] < 15'''),
        new_markdown_cell("## Overlay\n\nThe fitted mesh rendered with the fit's own camera "
                          "(`morphable.raster`), shaded and as a wireframe; green crosses: the detected "
                          "landmarks, red discs: the fitted model points."),
        new_code_cell('''\
from morphable.overlay import draw_overlay, face_box, save_overlay

# crop=0.15: cut to the face box (mesh and landmarks) widened by 15 % of its size per side
shaded = draw_overlay(photo, fit, mesh="shaded", crop=0.15)
wire = draw_overlay(photo, fit, mesh="wireframe", alpha=0.8, crop=0.15)
x0, y0, x1, y1 = face_box(fit, margin=0.15)
fig, axes = plt.subplots(1, 3, figsize=(12, 5))
for ax, img, title in zip(axes, (photo[y0:y1, x0:x1], shaded, wire), ("photo", "shaded fit", "wireframe")):
    ax.imshow(img)
    ax.set_title(title)
    ax.axis("off")
plt.show()
save_overlay(OUT / "overlay.png", photo, fit)'''),
        new_markdown_cell("## Export\n\nThe mesh with the model's texture coordinates, and the JSON "
                          "report that `morphable fit --report` writes."),
        new_code_cell('''\
import json

from morphable.io.mesh import read_mesh, write_mesh

write_mesh(OUT / "fit.obj", fit.vertices(0), model.triangles, model.uv, model.triangle_uv)
(OUT / "fit.json").write_text(json.dumps(fit.to_dict(images=[photo_path]), indent=2))
mesh = read_mesh(OUT / "fit.obj")
print(OUT / "fit.obj", mesh.vertices.shape, "vertices, extent (mm):", mesh.extents.round(1))'''),
        new_markdown_cell("## In 3D\n\n`morphable show fit.obj --landmarks` opens a pyvista window; "
                          "`--screenshot` renders off-screen (here, and on machines without a display)."),
        new_code_cell('''\
try:
    from morphable.viewer import show_mesh
except ImportError:  # the viz extra is missing
    show_mesh = None
if show_mesh is not None:
    shot = show_mesh(fit.vertices(0), model.triangles, landmarks=fit.vertices(0)[model.landmark_ids[model.landmark_ids >= 0]],
                     view="left", size=(480, 360), screenshot=OUT / "fit_3d.png")
    plt.figure(figsize=(5, 4))
    plt.imshow(Image.open(shot))
    plt.axis("off")
    plt.show()'''),
    ]


def scan_evaluation():
    return [
        new_markdown_cell("""\
# 02 — Evaluation against a scan: the Florence protocol on james

Synthetic videos of the james scan (cooperative, indoor, outdoor conditions) give landmarks;
each method reconstructs the face from a few frames; the reconstruction is aligned to the scan
(landmark similarity, 95 mm crop around the nose tip, ICP) and the point-to-plane error is
measured per vertex. Small settings here (2 conditions, 3 of 10 frames); the full run is

```
python -m evaluation.florence --scan ../shared/data/scans/james/james.obj \\
    --scan-landmarks ../shared/data/scans/james/james.ljson \\
    --methods ours ours-independent eos mean-face --report reports/florence_james.json \\
    --plot reports/florence_james.png --heatmaps reports/heatmaps
```"""),
        new_code_cell(SETUP),
        new_code_cell('''\
from evaluation.florence.protocol import format_table, run_protocol
from evaluation.scans import load_scan
from morphable import load_model

model = load_model("sfm")
scan = load_scan(DATA / "scans" / "james" / "james.obj", DATA / "scans" / "james" / "james.ljson")
print(f"scan: {scan.units}, inter-ocular {scan.interocular_mm:.1f} mm")
report, errors = run_protocol(scan, model, ["ours", "eos", "mean-face"], ["cooperative", "outdoor"],
                              n_sampled=3, n_frames=10, seed=0)
print(format_table(report))'''),
        new_markdown_cell("## Per-condition errors\n\n`evaluation.plots.condition_bars` "
                          "(also `python -m evaluation.plots report.json --out bars.png`)."),
        new_code_cell('''\
from PIL import Image

from evaluation.plots import condition_bars

bars = condition_bars(report, OUT / "florence_bars.png")
plt.figure(figsize=(7, 3.5))
plt.imshow(Image.open(bars))
plt.axis("off")
plt.show()
ok = [c for per in report["methods"].values() for c in per.values() if "mean_mm" in c]
assert ok and all(0 < c["mean_mm"] < 5 for c in ok)'''),
        new_markdown_cell("## Heat map\n\nWhere the error is: the per-vertex point-to-plane error "
                          "of `ours` (cooperative) on the aligned reconstruction, frontal view, "
                          "0–4 mm (grey: outside the crop)."),
        new_code_cell('''\
from evaluation.florence.protocol import save_heatmap
from evaluation.videos import frontal_frame

ours = next(m for m in errors if (m.method, m.condition) == ("ours", "cooperative"))
e = ours.mesh_errors
frame = frontal_frame(scan.landmarks, model.landmark_positions())
save_heatmap(OUT / "heatmap_ours_cooperative.png", ours.vertices, ours.triangles, e, frame, size=256)
fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
a.imshow(Image.open(OUT / "heatmap_ours_cooperative.png"))
a.axis("off")
a.set_title("ours, cooperative")
b.hist(e[np.isfinite(e)], bins=50, color="tab:blue")
b.set_xlabel("point-to-plane error (mm)")
b.set_ylabel("vertices")
plt.show()
print(f"median {np.nanmedian(e):.2f} mm, 95th percentile {np.nanpercentile(e, 95):.2f} mm")'''),
        new_markdown_cell("The same errors in 3D: `morphable show` takes a per-vertex `.npy` with "
                          "`--errors`."),
        new_code_cell('''\
try:
    from morphable.viewer import show_mesh
except ImportError:
    show_mesh = None
if show_mesh is not None:
    shot = show_mesh(ours.vertices, ours.triangles, errors=e, error_range=(0, 4), size=(480, 360),
                     screenshot=OUT / "errors_3d.png")
    plt.figure(figsize=(5, 4))
    plt.imshow(Image.open(shot))
    plt.axis("off")
    plt.show()'''),
    ]


def neural_renderer():
    return [
        new_markdown_cell("""\
# 03 — The Generative Adversarial Renderer (GAR)

`G(n, z)` renders a face image from a camera-frame normal map `n` (geometry, from the 3DMM
through `morphable.raster.normal_map`) and a latent code `z` (appearance: skin, light,
background). This notebook samples images, edits the geometry with the appearance fixed,
inverts the renderer for a latent code, and reconstructs and edits a real photo.

**Weights.** The generator is looked up in `$MORPHABLE_GAR_WEIGHTS`, then the committed
`neural/gar/weights/gar_tiny.pt` (model card: `neural/gar/weights/MODEL_CARD.md`), then
`runs/tiny/generator.pt` (written by `python -m neural.gar.train --config tiny --out runs/tiny`).
Without any, the generator below is **untrained**: the images are then structured noise shaped
by the normal maps — the cells show the mechanics, not the quality of a trained model."""),
        new_code_cell(SETUP + '''

import torch

from neural.gar.config import get_config
from neural.gar.networks import Generator, load_generator
from neural.gar.paths import default_generator_path

torch.manual_seed(0)
# the first generator found: $MORPHABLE_GAR_WEIGHTS or the committed weights, then a run
candidates = [default_generator_path(), REPO / "runs" / "tiny" / "generator.pt"]
weights = next((Path(c) for c in candidates if c and Path(c).is_file()), None)
if weights is not None:
    G = load_generator(weights)
    step = torch.load(weights, map_location="cpu", weights_only=True).get("step")
    print(f"trained generator: {weights} (step {step})")
else:
    G = Generator(get_config("tiny")).eval().requires_grad_(False)
    print("no trained weights found: an UNTRAINED tiny generator (random weights)")
R = G.config.resolution
print(f"resolution {R} px, z_dim {G.config.z_dim}")'''),
        new_markdown_cell("## Normal maps from the 3DMM\n\nRandom identities of the SFM, framed "
                          "at three yaw angles; camera-frame unit normals, zero on the background."),
        new_code_cell('''\
from morphable import load_model
from morphable.raster import frame_mesh, normal_map

model = load_model("sfm")
rng = np.random.default_rng(0)


def normals_of(vertices, yaw=0.0, pitch=0.0):
    cam = frame_mesh(model.mean, (R, R), yaw=yaw, pitch=pitch, margin=0.08)
    n = normal_map(vertices, model.triangles, cam, supersample=2)  # (R, R, 3)
    return torch.as_tensor(n, dtype=torch.float32).permute(2, 0, 1)  # (3, R, R)


identity = rng.standard_normal(model.n_identity)
face = model.vertices(identity)
yaws = (-30.0, 0.0, 30.0)
normals = torch.stack([normals_of(face, y) for y in yaws])
assert torch.allclose(normals.norm(dim=1)[normals.norm(dim=1) > 0], torch.tensor(1.0), atol=1e-4)'''),
        new_markdown_cell("## Samples\n\nEach row: a normal map, then four latent codes."),
        new_code_cell('''\
def show(images, rows, cols, titles=None, size=1.6):
    fig, axes = plt.subplots(rows, cols, figsize=(cols * size, rows * size), squeeze=False)
    for ax, img in zip(axes.ravel(), images):
        ax.imshow(np.clip(img.permute(1, 2, 0).numpy() * 0.5 + 0.5, 0, 1))
        ax.axis("off")
    if titles:
        for ax, t in zip(axes[0], titles):
            ax.set_title(t, fontsize=8)
    plt.show()


z = torch.randn(4, G.config.z_dim, generator=torch.Generator().manual_seed(1))
with torch.no_grad():
    grid = []
    for n in normals:
        imgs = G(n[None].expand(len(z), -1, -1, -1), z, noise="zero")
        grid += [n, *imgs]  # show() maps the normals [-1, 1] to RGB like the images
show(grid, len(normals), 1 + len(z), ["normals"] + [f"z{i}" for i in range(len(z))])
assert torch.isfinite(imgs).all() and imgs.shape == (len(z), 3, R, R)'''),
        new_markdown_cell("## Editing\n\nThe appearance `z` fixed, the geometry edited through the "
                          "3DMM: a smile (SFM blendshape `happiness`) and a turn of the head."),
        new_code_cell('''\
k = model.expression_names.index("happiness") if "happiness" in model.expression_names else 0
edits, titles = [], []
for w in (0.0, 0.5, 1.0):
    expr = np.zeros(model.n_expression)
    expr[k] = w
    edits.append(normals_of(model.vertices(identity, expr)))
    titles.append(f"{model.expression_names[k]} {w:g}")
for yaw in (-40.0, 40.0):
    edits.append(normals_of(face, yaw))
    titles.append(f"yaw {yaw:+g}")
edits = torch.stack(edits)
with torch.no_grad():
    out = G(edits, z[:1].expand(len(edits), -1), noise="zero")
show([*edits, *out], 2, len(edits), titles)
# a different geometry gives a different image for the same z
assert (out[0] - out[2]).abs().mean() > 1e-4'''),
        new_markdown_cell("## Inverting the renderer (latent code)\n\nGiven an image made by `G` from a "
                          "known normal map, recover its latent code by gradient descent on the L1 "
                          "distance — the appearance half of GAR inversion (the paper also optimises the "
                          "3DMM parameters through the normal map)."),
        new_code_cell('''\
target_z = torch.randn(1, G.config.z_dim, generator=torch.Generator().manual_seed(7))
n0 = normals[1:2]
with torch.no_grad():
    target = G(n0, target_z, noise="zero")
z_hat = torch.zeros(1, G.config.z_dim, requires_grad=True)
opt = torch.optim.Adam([z_hat], lr=0.05)
losses = []
for step in range(40):
    opt.zero_grad()
    loss = (G(n0, z_hat, noise="zero") - target).abs().mean()
    loss.backward()
    opt.step()
    losses.append(float(loss.detach()))
with torch.no_grad():
    recon = G(n0, z_hat, noise="zero")
print(f"L1 {losses[0]:.4f} -> {losses[-1]:.4f} in {len(losses)} steps")
show([target[0], recon[0]], 1, 2, ["target", "inverted"], size=2.2)
assert losses[-1] < losses[0]'''),
        new_markdown_cell("""\
## Reconstructing a photo through the GAR

The paper's method on a real photo: landmark fit (α, β, θ), then `z ← V(crop)` (the committed
inverter, when there is one), `ε ← 0`, then Adam over α, β, θ, z, ε through the fixed GAR
(`morphable.refinement.refine`; `morphable fit IMAGE --refine gar` on the command line). Few steps
here to keep the notebook quick; the CLI default is 100."""),
        new_code_cell('''\
from PIL import Image

from morphable.fitting import fit_landmarks
from morphable.io.landmark_files import read_pts
from morphable.refinement import edit, refine

photo_path = DATA / "images" / "image_0010.png"
photo = np.asarray(Image.open(photo_path).convert("RGB"))
fit = fit_landmarks(model, read_pts(photo_path.with_suffix(".pts"))[None], [photo.shape[1::-1]])
gar = None if weights is None else {"weights": str(weights)}
refined, report, state = refine(photo, fit, "gar", steps=30, return_state=True,
                                renderer_options=gar or {"allow_untrained": True})
photo_loss = report["photometric_loss"]
print(f"photometric loss {photo_loss[0]:.4f} -> {photo_loss[-1]:.4f} in {len(photo_loss)} steps, "
      f"{report['runtime_s']:.1f} s; latent from {report['latent_init']}")
assert np.isfinite(photo_loss).all() and photo_loss[-1] < photo_loss[0]'''),
        new_markdown_cell("## Editing the reconstruction\n\nThe recovered face under another pose and "
                          "expression, re-rendered with the recovered z and ε (`morphable edit`)."),
        new_code_cell('''\
to_t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float32) * 2 - 1).permute(2, 0, 1)
turned = edit(state, yaw=20.0)
smiling = edit(state, expression={"happiness": 0.8})
show([to_t(state.target), to_t(state.rendered), to_t(turned), to_t(smiling)], 1, 4,
     ["crop", "reconstruction", "yaw 20", "happiness 0.8"], size=2.2)
assert np.isfinite(turned).all() and np.abs(turned - state.rendered).mean() > 1e-3'''),
        new_markdown_cell("""\
## Next

```
python -m neural.gar.train --config tiny --out runs/tiny            # train your own, then rerun
python -m evaluation.gar_quality --report reports/gar.json --generator runs/tiny/generator.pt
python -m evaluation.gar_ablation --report ablate.json          # the reconstruction ablations
```"""),
    ]


NOTEBOOKS = {"01_fit_a_photo.ipynb": fit_a_photo, "02_scan_evaluation.ipynb": scan_evaluation,
             "03_neural_renderer.ipynb": neural_renderer}


def build(name: str) -> nbformat.NotebookNode:
    nb = new_notebook(cells=NOTEBOOKS[name]())
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    for i, cell in enumerate(nb.cells):
        cell["id"] = f"{Path(name).stem[:2]}-{i:02d}"  # stable ids: rebuilding changes nothing
    return nb


def main() -> int:
    for name in NOTEBOOKS:
        nbformat.write(build(name), HERE / name)
        print(HERE / name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
