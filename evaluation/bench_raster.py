"""Rasterisation speed: normal-map bakes of SFM, ICT and the james scan at 256^2 and 512^2,
numpy and torch paths, forward and backward, and the visibility pass against trimesh's ray
queries on the same rays.

Run: ``.venv/bin/python -m evaluation.bench_raster [--repeat 7] [--threads 1] [--out table.md]``
(``--trimesh-numpy`` adds trimesh's numpy intersector, which takes minutes.)

Every figure is the median wall time of ``--repeat`` runs in this process (after one warm-up
run), the fastest run in parentheses. Columns:

- visibility: ray casting with the mesh's Embree scene cached (only the camera changed).
- +rebuild: visibility when the vertices changed since the last call (the scene is rebuilt).
- bake numpy: ``normal_map`` of a mesh seen before (only the camera changed): visibility and
  interpolation, with the mesh's Embree scene and vertex normals taken from the cache.
- bake new: ``normal_map`` when the vertices changed since the last call (scene and vertex
  normals built again).
- torch fwd / fwd+bwd: the differentiable ``normal_map`` (float32, visibility fixed) and its
  backward pass to the vertices: one gradient step of a fit that keeps the visibility.
- step: a gradient step that also recomputes the visibility for the new vertices.
- CPU: process CPU time (all threads) of the column before it; on a machine shared with other
  jobs it estimates the wall time the call would take alone (Embree's threads add up).
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from morphable.logs import add_verbosity_arguments, configure, verbosity

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


class Timing(float):
    """A median wall time in ms that also carries the fastest run (``.min``)."""

    def __new__(cls, median, fastest):
        obj = super().__new__(cls, median)
        obj.min = fastest
        return obj

    def __format__(self, spec):
        return f"{float(self):{spec}} ({self.min:{spec}})"


def _median_ms(fn, repeat, cpu=False):
    """Median wall time in ms (a :class:`Timing`, with the fastest run); with ``cpu=True``
    also the median CPU time of this process (all its threads), which other processes on a
    shared machine do not inflate."""
    fn()
    wall, proc = [], []
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        proc.append(time.process_time() - c)
    timing = Timing(1e3 * statistics.median(wall), 1e3 * min(wall))
    if cpu:
        return timing, 1e3 * statistics.median(proc)
    return timing


def meshes():
    from morphable import load_model
    from morphable.raster.inputs import load_mesh

    sfm, ict = load_model("sfm"), load_model("ict")
    scan = load_mesh(DATA / "scans/james/james.obj")
    return [("SFM", sfm.mean.astype(np.float64), sfm.triangles),
            ("ICT", ict.mean.astype(np.float64), ict.triangles),
            ("james scan", scan.vertices, scan.triangles)]


def bench(repeat=7, sizes=(256, 512), trimesh_size=256, threads=1, trimesh_numpy=False):
    import torch

    from morphable.raster import frame_mesh, normal_map, visibility

    # torch's OpenMP workers spin-wait: on a shared, busy machine one thread is faster
    torch.set_num_threads(threads)
    rows = []
    rng = np.random.default_rng(0)
    for name, v, t in meshes():
        for size in sizes:
            cam = frame_mesh(v, (size, size), yaw=20, kind="perspective")
            vis = visibility(v, t, cam)
            r = {"mesh": name, "vertices": len(v), "triangles": len(t), "size": size,
                 "coverage": float(vis.mask.mean())}
            r["visibility"] = _median_ms(lambda: visibility(v, t, cam), repeat)
            jitter = [v + rng.normal(scale=1e-3, size=v.shape) for _ in range(repeat + 1)]
            it = iter(jitter)
            r["+rebuild"] = _median_ms(lambda: visibility(next(it), t, cam), repeat)
            r["bake numpy"], r["bake CPU"] = _median_ms(lambda: normal_map(v, t, cam), repeat,
                                                        cpu=True)
            it = iter(jitter)
            r["bake new"] = _median_ms(lambda: normal_map(next(it), t, cam), repeat)
            vt = torch.tensor(v, dtype=torch.float32, requires_grad=True)
            tt = torch.as_tensor(t)
            target = torch.zeros(size, size, 3)

            def forward():
                with torch.no_grad():
                    normal_map(vt, tt, vis=vis)

            def step():
                vt.grad = None
                loss = ((normal_map(vt, tt, vis=vis) - target) ** 2).sum()
                loss.backward()

            r["torch fwd"] = _median_ms(forward, repeat)
            r["torch fwd+bwd"], r["fwd+bwd CPU"] = _median_ms(step, repeat, cpu=True)
            it = iter(jitter)

            def full_step():
                x = next(it)
                vis_k = visibility(x, t, cam)
                vt.grad = None
                loss = ((normal_map(vt, tt, vis=vis_k) - target) ** 2).sum()
                loss.backward()

            r["step"] = _median_ms(full_step, repeat)
            if size == trimesh_size:
                r.update(compare_trimesh(v, t, cam, vis, repeat=max(1, repeat // 3),
                                         numpy_backend=trimesh_numpy))
                r.update(compare_zbuffer(v, t, cam, vis, repeat))
            rows.append(r)
    return rows


def _trimesh_backends(numpy_backend=False):
    """trimesh's ray intersectors that can run here: embree (needs ``embreex``) and, if
    asked, the numpy one (needs ``rtree``)."""
    out = {}
    try:
        import embreex  # noqa: F401
        from trimesh.ray import ray_pyembree

        out["embree (embreex)"] = ray_pyembree.RayMeshIntersector
    except ImportError:
        pass
    try:
        import rtree  # noqa: F401
        from trimesh.ray import ray_triangle

        if numpy_backend:
            out["numpy (ray_triangle)"] = ray_triangle.RayMeshIntersector
    except ImportError:
        pass
    return out


def numpy_zbuffer(v, t, cam):
    """A vectorised numpy z-buffer rasteriser for perspective cameras, the hand-written
    alternative to ray casting kept here only as a peer: every triangle's bounding-box
    pixels, edge functions, perspective-correct depth, ``np.minimum.at`` depth test
    -> (H, W) triangle ids."""
    W, H = cam.image_size
    p, d = cam.project(v), cam.depth(v)
    P = p[t]
    lo = np.clip(np.ceil(P.min(1)), 0, [W, H]).astype(np.int64)
    hi = np.clip(np.floor(P.max(1)), -1, [W - 1, H - 1]).astype(np.int64)
    n = np.maximum(hi - lo + 1, 0)
    cnt = n[:, 0] * n[:, 1]
    tri = np.repeat(np.arange(len(t)), cnt)
    k = np.arange(len(tri)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    px = lo[tri, 0] + k % n[tri, 0]
    py = lo[tri, 1] + k // n[tri, 0]
    a, b, c = P[tri, 0], P[tri, 1], P[tri, 2]

    def edge(p0, p1):
        return (p1[:, 0] - p0[:, 0]) * (py - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (px - p0[:, 0])

    w = np.stack([edge(b, c), edge(c, a), edge(a, b)], 1)
    area = w.sum(1)
    ok = (((w >= 0).all(1)) | ((w <= 0).all(1))) & (area != 0)
    tri, px, py, w, area = tri[ok], px[ok], py[ok], w[ok], area[ok]
    depth = 1.0 / (w / area[:, None] / d[t[tri]]).sum(1)
    key = py * W + px
    zbuf = np.full(W * H, np.inf)
    np.minimum.at(zbuf, key, depth)
    win = depth <= zbuf[key]
    tid = np.full(W * H, -1)
    tid[key[win]] = tri[win]
    return tid.reshape(H, W)


def compare_zbuffer(v, t, cam, vis, repeat):
    ms = _median_ms(lambda: numpy_zbuffer(v, t, cam), repeat)
    same = float((numpy_zbuffer(v, t, cam) == vis.triangle_id).mean())
    return {"zbuffer ms": ms, "zbuffer same": same}


def compare_trimesh(v, t, cam, vis, repeat=2, numpy_backend=False):
    """The same rays through trimesh's first-hit queries: time and agreement per backend."""
    import trimesh

    from morphable.raster import visibility

    o, d = cam.rays()
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    ours = _median_ms(lambda: visibility(v, t, cam), repeat)
    rng = np.random.default_rng(1)
    jitter = iter([v + rng.normal(scale=1e-3, size=v.shape) for _ in range(repeat + 1)])
    ours_new = _median_ms(lambda: visibility(next(jitter), t, cam), repeat)
    found = {}
    for backend, cls in _trimesh_backends(numpy_backend).items():
        cached = cls(trimesh.Trimesh(v, t, process=False))
        ms = _median_ms(lambda: cached.intersects_first(o, d), repeat)
        # a fresh mesh: trimesh builds its acceleration structure again, as for new vertices
        ms_new = _median_ms(lambda: cls(trimesh.Trimesh(v, t, process=False)).intersects_first(o, d),
                            repeat)
        agree = float((cached.intersects_first(o, d).reshape(vis.shape) == vis.triangle_id).mean())
        found[backend] = {"ms": ms, "ms new": ms_new, "same": agree}
    return {"trimesh": found, "open3d ms": ours, "open3d new ms": ours_new}


COLUMNS = ["mesh", "vertices", "size", "visibility", "+rebuild", "bake numpy", "bake CPU",
           "bake new", "torch fwd", "torch fwd+bwd", "fwd+bwd CPU", "step"]


def table(rows) -> str:
    head = "| " + " | ".join(COLUMNS) + " |\n|" + "---|" * len(COLUMNS) + "\n"
    body = ""
    for r in rows:
        cells = [r["mesh"], str(r["vertices"]), f"{r['size']}²"]
        cells += [f"{r[c]:.1f}" for c in COLUMNS[3:]]
        body += "| " + " | ".join(cells) + " |\n"
    cmp_rows = [r for r in rows if "trimesh" in r]
    if cmp_rows:
        body += ("\nVisibility pass against trimesh's first-hit ray queries on the same rays "
                 "(`Camera.rays`, all pixels for trimesh, the mesh's bounding box for us). "
                 "cached: acceleration structure kept; new: built for changed vertices.\n\n"
                 "| mesh | size | trimesh backend | trimesh cached | morphable cached | ratio "
                 "| trimesh new | morphable new | ratio | same triangle |\n"
                 "|---|---|---|---|---|---|---|---|---|---|\n")
    for r in cmp_rows:
        if not r["trimesh"]:
            body += (f"| {r['mesh']} | {r['size']}² | none installed (embreex, rtree) "
                     "| | | | | | | |\n")
        for backend, c in r["trimesh"].items():
            a, b = r["open3d ms"], r["open3d new ms"]
            body += (f"| {r['mesh']} | {r['size']}² | {backend} | {c['ms']:.1f} | {a:.1f} | "
                     f"{c['ms'] / a:.1f}x | {c['ms new']:.1f} | {b:.1f} | {c['ms new'] / b:.1f}x | "
                     f"{100 * c['same']:.2f}% |\n")
    zb = [r for r in rows if "zbuffer ms" in r]
    if zb:
        body += ("\nRay casting against a hand-written vectorised numpy z-buffer rasteriser "
                 "(`numpy_zbuffer` here):\n\n| mesh | size | numpy z-buffer ms | "
                 "morphable visibility ms | ratio | same triangle |\n|---|---|---|---|---|---|\n")
    for r in zb:
        body += (f"| {r['mesh']} | {r['size']}² | {r['zbuffer ms']:.1f} | {r['visibility']:.1f} "
                 f"| {r['zbuffer ms'] / r['visibility']:.1f}x | {100 * r['zbuffer same']:.2f}% |\n")
    return head + body


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--trimesh-numpy", action="store_true",
                   help="also time trimesh's numpy ray intersector (slow)")
    p.add_argument("--out", help="also write the markdown table here")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    import os

    rows = bench(args.repeat, tuple(args.sizes), threads=args.threads,
                 trimesh_numpy=args.trimesh_numpy)
    load = os.getloadavg()[0]
    text = (f"Times in ms: median of {args.repeat} (fastest), perspective camera, yaw 20°, "
            f"{os.cpu_count()} CPUs (load average {load:.1f} at the end), torch threads "
            f"{args.threads}.\n\n" + table(rows))
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return rows


if __name__ == "__main__":
    main()
