"""The mutation check: does the suite catch a wrong result, not only a crash?

Each entry of :data:`FAULTS` is a small deliberate fault (one piece of code changed) in a key
module and the tests that should catch it. :func:`check` copies the working tree (the files git
tracks and the untracked ones it does not ignore, uncommitted changes included) into a scratch
folder with ``shared`` beside it (a link to ``../shared``), applies each fault there alone, runs
its tests and says whether they failed (the fault is *caught*) or passed (*missed*). The
working tree itself is never written.

Every run first runs each fault's tests on the unchanged copy (they must pass, or a fault would
look caught by a test that fails anyway), and runs all tests with ``MORPHABLE_DATA``,
``MORPHABLE_LANDMARK_WEIGHTS`` and ``MORPHABLE_GAR_WEIGHTS`` pointing at nothing, which
``tests/conftest.py`` must clear.

Run it before a change to these modules lands (docs/contributing.md)::

    python -m evaluation.mutation_check                 # every fault (7 minutes on 2 cores)
    python -m evaluation.mutation_check --list          # the faults and their tests
    python -m evaluation.mutation_check --only tracked-identity-is-zero --no-baseline

Exit status 0 when every fault is caught; 1 when one is missed, or its tests fail on the
unchanged copy, or cannot run; 2 for bad arguments.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from morphable.errors import InputError, one_line_errors

__all__ = ["Fault", "FAULTS", "scratch_copy", "apply_fault", "run_tests", "check", "main"]

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Fault:
    """A deliberate fault: in ``path`` (relative to the repository), the text ``old`` (found
    exactly once) replaced by ``new``; ``tests`` the pytest arguments (node ids, relative to the
    repository) that must fail with it; ``what`` says what goes wrong."""

    name: str
    path: str
    old: str
    new: str
    tests: tuple
    what: str


FAULTS = (
    # --- issue 57's four faults ---------------------------------------------------------------
    Fault("written-mesh-is-the-mean", "morphable/pipeline/outputs.py",
          "write_mesh(mesh, result.mesh_vertices(),", "write_mesh(mesh, fit.model.mean.reshape(-1, 3),",
          ("tests/test_pipeline.py::test_every_mesh_format_holds_the_fitted_face",),
          "every mesh a fit writes (OBJ, PLY, STL, OFF, glb) holds the model's mean, not the fitted face"),
    Fault("written-mesh-is-the-mean-fit-command", "morphable/pipeline/outputs.py",
          "write_mesh(mesh, result.mesh_vertices(),", "write_mesh(mesh, fit.model.mean.reshape(-1, 3),",
          ("tests/test_fitting.py::test_cli_fit_writes_mesh_and_report",),
          "the same, caught by `morphable fit --out-mesh` read back"),
    Fault("written-mesh-is-the-mean-fit-batch", "morphable/pipeline/outputs.py",
          "write_mesh(mesh, result.mesh_vertices(),", "write_mesh(mesh, fit.model.mean.reshape(-1, 3),",
          ("tests/test_fit_batch.py::test_uninterrupted_run",),
          "the same, caught by fit-batch's items read back"),
    Fault("tracked-identity-is-zero", "morphable/tracking/single.py",
          "    alpha = res.identity\n", "    alpha = np.zeros_like(res.identity)\n",
          ("tests/test_tracking.py",),
          "the tracked identity set to zeros (the mean face)"),
    Fault("gar-normal-map-mirrored", "neural/gar/renderer.py",
          'img = self.generator(normal_map.float(), appearance["z"]',
          'img = self.generator(normal_map.float().flip(-1), appearance["z"]',
          ("tests/test_renderer_plugins.py::test_committed_gar_follows_the_normals_it_is_given",),
          "the GAR plugin renders its normal map mirrored along the image's x axis"),
    Fault("landmarks-shifted-3-percent", "neural/landmarks/detector.py",
          'pts.append(crop_to_image(out["points"], crop_theta(b, (W, H)), (W, H)))',
          'pts.append(crop_to_image(out["points"], crop_theta(b, (W, H)), (W, H))\n'
          '                       + 0.03 / 1.4 * box_side(b)[:, None, None] * np.array([1.0, 0.0]))',
          ("tests/test_landmark_detector.py::test_committed_weights_alone_against_annotated_photos",),
          "the landmark network's points moved right by 3 % of the face (its framing side / 1.4)"),
    # --- the weak spots mended with them -----------------------------------------------------
    Fault("fit-batch-pose-reversed", "morphable/pipeline/batch.py",
          "for a in e] for e in res.euler_deg]", "for a in e[::-1]] for e in res.euler_deg]",
          ("tests/test_fit_batch.py::test_uninterrupted_run",),
          "fit-batch's results log gives roll, pitch, yaw for yaw, pitch, roll"),
    Fault("fit-batch-identity-not-fitted", "morphable/pipeline/batch.py",
          'landmark_std_px=options.get("landmark_std_px", 1.0))',
          "landmark_std_px=100.0)",
          ("tests/test_fit_batch.py::test_uninterrupted_run",),
          "fit-batch's items fitted with 100 px landmark noise: the identity stays near the mean"),
    Fault("fit-batch-rerun-refits", "morphable/batch.py",
          "todo = [it for it in items if it.id not in done]", "todo = list(items)",
          ("tests/test_fit_batch.py::test_a_rerun_does_nothing",),
          "a re-run fits (and records) every item again"),
    Fault("batch-keeps-a-killed-runs-files", "morphable/batch.py",
          "shutil.rmtree(stale, ignore_errors=True)", "pass",
          ("tests/test_batch.py::test_kill_and_resume",
           "tests/test_fit_batch.py::test_kill_and_resume_matches_uninterrupted"),
          "a resumed run leaves the killed item's temporary folder behind"),
    Fault("texture-command-on-the-mean-face", "morphable/cli/texture.py",
          "np.stack([m.vertices for m in meshes])", "np.stack([m.model.vertices() for m in meshes])",
          ("tests/test_texture.py::test_fit_out_texture_round_trip",),
          "`morphable texture` samples the photo with the mean face instead of the report's"),
    Fault("render-sh-ignored", "morphable/cli/render.py",
          "light = np.array(c).reshape(9, 3) if len(c) == 27 else np.array(c)", "light = None",
          ("tests/test_raster_cli.py::test_render_textured_scan_and_model",),
          "`morphable render --sh` lights with the default lamp instead"),
    Fault("florence-ours-is-the-mean-face", "evaluation/florence/methods.py",
          "        v = res.vertices().mean(0)\n", "        v = self.model.vertices()\n",
          ("tests/test_florence.py::test_command_on_james",),
          "the Florence protocol's `ours` reports the mean face"),
    Fault("read-pts-one-based", "morphable/io/landmark_files.py",
          "    return pts - 1.0\n", "    return pts\n",
          ("morphable/io/landmark_files.py::morphable.io.landmark_files.read_pts",),
          ".pts points read 1-based (caught by the docstring's example, no longer skipped)"),
    # --- issue 55's footage tracker ----------------------------------------------------------
    Fault("footage-people-never-joined", "morphable/tracking/footage.py",
          "if d < best and not any(", "if False and not any(",
          ("tests/test_footage.py::test_join_tracks_by_descriptor_never_two_at_once",
           "tests/test_footage.py::test_shots_tracks_and_people"),
          "every track its own person: a person is not joined across cuts"),
    Fault("footage-fades-not-cut", "morphable/shots.py",
          "sorted({c for c in away_from_dark + self._fade_cuts", "sorted({c for c in away_from_dark",
          ("tests/test_footage.py::test_cuts_and_fades_are_found_and_a_pan_is_not_a_cut",),
          "a fade through black is not a shot boundary"),
    Fault("conftest-keeps-the-environment", "tests/conftest.py",
          "    del os.environ[_name]\n", "    pass\n",
          ("tests/test_renderer_plugins.py::test_committed_gar_follows_the_normals_it_is_given",),
          "the suite takes $MORPHABLE_GAR_WEIGHTS (pointing at nothing here) from the caller"),
)
"""The faults, one at a time: issue 57's four (each writer of the mesh separately) and the
weak spots mended with them.

:meta hide-value:
"""

POISON = ("MORPHABLE_DATA", "MORPHABLE_LANDMARK_WEIGHTS", "MORPHABLE_GAR_WEIGHTS")
"""Variables set to paths of nothing for every run: the suite must not read them."""


def scratch_copy(dest: Path, repo: Path = REPO) -> Path:
    """``repo``'s working tree (tracked files and untracked ones git does not ignore) copied
    into ``dest/<repo's name>``, with ``dest/shared`` a link to ``repo/../shared``; returns the
    copy's root."""
    listed = subprocess.run(["git", "ls-files", "-z", "-c", "-o", "--exclude-standard"], cwd=repo,
                            capture_output=True, check=False)
    if listed.returncode:
        raise InputError(f"{repo}: git ls-files failed ({listed.stderr.decode().strip()})")
    root = dest / repo.name
    for name in sorted(set(listed.stdout.decode().split("\0")) - {""}):
        src = repo / name
        if src.is_file():          # listed but deleted in the working tree: not copied
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, root / name)
    shared = repo.parent / "shared"
    if shared.exists():
        (dest / "shared").symlink_to(shared.resolve(), target_is_directory=True)
    return root


def apply_fault(fault: Fault, root: Path) -> str:
    """Put ``fault`` into the copy at ``root``; returns the file's text before (to undo it).
    InputError when its ``old`` text is not found exactly once (the entry is out of date)."""
    path = root / fault.path
    text = path.read_text()
    n = text.count(fault.old)
    if n != 1 or fault.old == fault.new:
        raise InputError(f"{fault.path}: fault {fault.name!r}: its text is found {n} times, "
                         "not once (update evaluation/mutation_check.py)")
    path.write_text(text.replace(fault.old, fault.new))
    return text


def _environment(root: Path, nothing: Path) -> dict:
    """The environment of a test run in the copy: its root first on PYTHONPATH (in place of
    this repository), the variables of :data:`POISON` pointing at ``nothing``."""
    keep = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep)
            if p and Path(p).resolve() != REPO]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), *keep])}
    env.update({name: str(nothing / name.lower()) for name in POISON})
    return env


def run_tests(root: Path, tests, env: dict, timeout: float = 600.0) -> tuple:
    """pytest on ``tests`` in the copy -> (exit status, its last line, seconds)."""
    start = time.monotonic()
    try:
        done = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                               *tests], cwd=root, env=env, capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        return None, f"no answer in {timeout:.0f} s", time.monotonic() - start
    lines = [ln for ln in done.stdout.splitlines() if ln.strip()]
    return done.returncode, lines[-1] if lines else done.stderr.strip()[-200:], time.monotonic() - start


def check(faults=FAULTS, baseline: bool = True, timeout: float = 600.0, keep: bool = False,
          out=sys.stdout) -> list:
    """Apply each fault alone to a scratch copy and run its tests -> one dict per fault:
    ``name``, ``result`` ("caught", "MISSED" or "error"), ``summary`` (pytest's last line),
    ``seconds``. With ``baseline``, each fault's tests run first on the unchanged copy; should
    they fail there, the check ends with that one row (result "failed")."""
    scratch = Path(tempfile.mkdtemp(prefix="mutation-check-"))
    rows = []
    try:
        root = scratch_copy(scratch)
        env = _environment(root, scratch / "nothing")
        for tests in dict.fromkeys(f.tests for f in faults) if baseline else ():
            rc, line, seconds = run_tests(root, tests, env, timeout)
            print(f"unchanged  {' '.join(tests)}: {line} ({seconds:.0f} s)", file=out, flush=True)
            if rc != 0:     # every fault would look caught
                return [{"name": f"{' '.join(tests)} without a fault", "result": "failed",
                         "summary": line, "seconds": seconds}]
        for fault in faults:
            before = apply_fault(fault, root)
            try:
                rc, line, seconds = run_tests(root, fault.tests, env, timeout)
            finally:
                (root / fault.path).write_text(before)
            result = "caught" if rc == 1 else "MISSED" if rc == 0 else "error"
            rows.append({"name": fault.name, "result": result, "summary": line, "seconds": seconds})
            print(f"{result:<7}  {fault.name}: {line} ({seconds:.0f} s)", file=out, flush=True)
    finally:
        if keep:
            print(f"scratch copy kept in {scratch}", file=out)
        else:
            shutil.rmtree(scratch, ignore_errors=True)
    return rows


def _list(faults, out=sys.stdout) -> None:
    for f in faults:
        print(f"{f.name}\n    {f.path}: {f.what}\n    tests: {' '.join(f.tests)}", file=out)


@one_line_errors("python -m evaluation.mutation_check")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.mutation_check",
                                description="apply each listed fault to a scratch copy of the working "
                                            "tree, run its tests, report the faults the suite misses")
    p.add_argument("--list", action="store_true", help="list the faults and their tests, run nothing")
    p.add_argument("--only", nargs="+", metavar="NAME", help="these faults only (default: all)")
    p.add_argument("--no-baseline", action="store_true",
                   help="skip the run of the tests on the unchanged copy")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds per pytest run (default 600)")
    p.add_argument("--keep", action="store_true", help="keep the scratch copy (its path is printed)")
    args = p.parse_args(argv)
    names = [f.name for f in FAULTS]
    unknown = [n for n in args.only or () if n not in names]
    if unknown:
        raise InputError(f"--only: no fault {unknown[0]!r}; the faults: {', '.join(names)}")
    faults = [f for f in FAULTS if args.only is None or f.name in args.only]
    if args.list:
        _list(faults)
        return 0
    start = time.monotonic()
    rows = check(faults, baseline=not args.no_baseline, timeout=args.timeout, keep=args.keep)
    caught = sum(r["result"] == "caught" for r in rows)
    print(f"{caught} of {len(rows)} faults caught in {(time.monotonic() - start) / 60:.1f} min"
          + "".join(f"; {r['result']}: {r['name']}" for r in rows if r["result"] != "caught"))
    return 0 if caught == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
