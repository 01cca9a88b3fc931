"""Find models by name or path, and download the public originals into the user cache.

Search order for a named model: each folder of ``$MORPHABLE_DATA`` (``os.pathsep``-separated),
then ``../shared/data/models`` next to the repository, then ``~/.cache/morphable``
(``$XDG_CACHE_HOME/morphable``).
"""
from __future__ import annotations

import functools
import hashlib
import io
import os
import shutil
import tempfile
import zipfile
from pathlib import Path

from ..errors import InputError

__all__ = ["MODELS", "DEFAULT_MODEL", "search_path", "cache_dir", "find_model", "load_model",
           "download", "sha256"]

DEFAULT_MODEL = "sfm"
"""The model :func:`load_model` and the commands load when none is named."""

_EOS_SHARE = "https://raw.githubusercontent.com/patrikhuber/eos/v1.5.0/share/"
_ICT_ZIP = "https://github.com/ICT-VGL/ICT-FaceKit/archive/refs/heads/master.zip"

# name -> folder under a search-path root, file that marks it, licence, download recipe.
MODELS = {
    "sfm": {
        "folder": "sfm",
        "marker": "sfm_shape_3448.bin",
        "description": "Surrey Face Model, 3448 vertices, 63 shape modes, 6 expression blendshapes",
        "license": "free for non-commercial use (cvssp.org/facemodel); eos code Apache-2.0",
        "url": _EOS_SHARE,
        "files": {
            "sfm_shape_3448.bin": "43750338ae533e7fb981e924b6f67ebde3d292f15ec4fc886ae5af14308ad980",
            "expression_blendshapes_3448.bin":
                "a77c81712fc5e8b08a1be4cd2824d51514e5bde6578109ae5240dfb3489efd43",
            "ibug_to_sfm.txt": "810810c457184526c7d54305ecbc5da764e2431b5e66025d921a7d424aebfac9",
            "sfm_model_contours.json":
                "c9e69bfa995ab19ac6b27abb07729eb0520a00bb192be12426ca6bce76f3fded",
            "sfm_reference_symmetry.txt":
                "d26e02dbb2cf72bfa88bc6bf6f175bf261bae7aff00509cc0ff277675f2fff47",
        },
    },
    "ict": {
        "folder": "ict-facekit",
        "marker": "ict_face_model.npz",
        "alt_marker": "generic_neutral_mesh.obj",
        "description": "ICT FaceKit light, 26719 vertices, 100 identity modes, 53 ARKit blendshapes",
        "license": "MIT (USC ICT Vision and Graphics Lab)",
        "url": _ICT_ZIP,
        "archive_folder": "FaceXModel/",
        # files whose published content we know; the rest of the archive is taken as is
        "files": {
            "generic_neutral_mesh.obj":
                "eedbc2576d8e5ea57f55255b8f98263213a1efb5431d8bfceed1d7aef10271f9",
            "identity000.obj": "918160cf82d541336b4c367cf93199c9827832bde02511b8fbdf9019d6f1a773",
            "identity001.obj": "325115059deb6691cb2d55da07ae38bb08ce36e4ea146982f294a17513155b3b",
            "jawOpen.obj": "8d84355e10f48b05550980cee385bcd426f4797090da76a20de0535bb2f99f4a",
            "mouthSmile_L.obj": "91794e73cef330f1c7d1f4541723544708536b39d5dd6ed35fd8f83f676b7af4",
            "vertex_indices.json":
                "4f9b35306299980dd46bee4a6b79bb95dfae1953693b74b35a64f7febfd081a5",
        },
    },
}


def cache_dir() -> Path:
    """The user cache for downloaded models (``$XDG_CACHE_HOME/morphable``)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "morphable"


def search_path() -> list[Path]:
    """Folders searched for named models, in order."""
    roots = [Path(p) for p in os.environ.get("MORPHABLE_DATA", "").split(os.pathsep) if p]
    repo = Path(__file__).resolve().parents[2]
    return roots + [repo.parent / "shared" / "data" / "models", cache_dir()]


def find_model(name_or_path) -> Path:
    """Resolve a model name (``sfm``, ``ict``) or a path to the file or folder to load."""
    p = Path(name_or_path)
    if str(name_or_path) not in MODELS:
        if p.exists():
            return p
        raise InputError(f"{name_or_path}: unknown model (not a file, not one of "
                         f"{', '.join(MODELS)})")
    spec = MODELS[str(name_or_path)]
    for root in search_path():
        folder = root / spec["folder"]
        for marker in (spec["marker"], spec.get("alt_marker")):
            if marker and (folder / marker).is_file():
                return folder / marker if marker.endswith(".npz") else folder
    raise InputError(f"model {name_or_path!r} not found in {', '.join(map(str, search_path()))}; "
                     f"run 'morphable download {name_or_path}' or set MORPHABLE_DATA")


def _loader(path: Path):
    from . import bfm, eos, flame, ict, native

    if path.is_dir():
        if (path / "generic_neutral_mesh.obj").is_file():
            return ict.load_ict_folder
        if any(path.glob("*.bin")):
            return eos.load_eos
        raise InputError(f"{path}: folder holds no known model format")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        import numpy as np

        try:
            with np.load(path, allow_pickle=False) as d:
                keys = set(d.files)
        except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
            raise InputError(f"{path}: cannot read npz ({e})") from None
        return native.load_model_npz if "format" in keys else ict.load_ict_npz
    loaders = {".bin": eos.load_eos, ".h5": bfm.load_bfm_h5, ".pkl": flame.load_flame_pkl}
    if suffix not in loaders:
        raise InputError(f"{path}: unknown model format {suffix!r} (.bin .npz .h5 .pkl or a folder)")
    return loaders[suffix]


@functools.lru_cache(maxsize=8)
def _load_cached(path: str, mtime: float, name: str):
    p = Path(path)
    return _loader(p)(p, name=name)


def load_model(name_or_path=DEFAULT_MODEL):
    """Load a morphable model by name (``"sfm"``, ``"ict"``) or from a path.

    Models are cached per process (keyed by path and modification time); treat the returned
    object as read-only.

    Examples
    --------
    >>> from morphable import load_model
    >>> model = load_model("sfm")
    >>> model.n_vertices, model.n_identity, model.n_expression
    (3448, 63, 6)
    """
    path = find_model(name_or_path)
    name = str(name_or_path) if str(name_or_path) in MODELS else path.stem
    return _load_cached(str(path.resolve()), path.stat().st_mtime, name)


def sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _fetch(url: str) -> bytes:
    import urllib.request          # http, email and ssl with it: only a download needs them

    try:
        with urllib.request.urlopen(url, timeout=60) as r:
            return r.read()
    except (OSError, ValueError) as e:
        raise InputError(f"{url}: download failed ({e})") from None


def download(name: str, dest: Path | None = None, url: str | None = None) -> Path:
    """Download the public original files of model ``name`` into ``dest`` (default: the cache).

    Every file with a known sha256 is checked; on a mismatch nothing is installed. ``url``
    overrides the source (a ``file://`` folder or archive works, which is how it is tested).

    Returns
    -------
    Path of the installed model folder.
    """
    if name not in MODELS:
        raise InputError(f"{name}: unknown model (known: {', '.join(MODELS)})")
    spec = MODELS[name]
    target = Path(dest or cache_dir()) / spec["folder"]
    created = not target.parent.exists()
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(dir=target.parent, prefix=f".{spec['folder']}."))
    except OSError as e:
        raise InputError(f"{target.parent}: cannot create the download folder ({e.strerror or e})") from None
    ok = False
    try:
        source = url or spec["url"]
        if "archive_folder" in spec:
            prefix = spec["archive_folder"]
            try:
                archive = zipfile.ZipFile(io.BytesIO(_fetch(source)))
            except zipfile.BadZipFile:
                raise InputError(f"{source}: not a zip archive") from None
            members = [m for m in archive.namelist() if prefix in m and not m.endswith("/")]
            if not members:
                raise InputError(f"{source}: archive has no {prefix} folder")
            for m in members:
                (staging / Path(m).name).write_bytes(archive.read(m))
        else:
            for fname in spec["files"]:
                (staging / fname).write_bytes(_fetch(source.rstrip("/") + "/" + fname))
        for fname, digest in spec["files"].items():
            f = staging / fname
            if not f.is_file():
                raise InputError(f"{source}: {fname} is missing from the download")
            if sha256(f) != digest:
                raise InputError(f"{source}: {fname} has the wrong sha256 (corrupt or changed upstream)")
        if target.exists():
            shutil.rmtree(target)
        staging.rename(target)
        ok = True
        return target
    finally:
        if staging.exists():
            shutil.rmtree(staging)
        if created and not ok:  # a failed download leaves nothing behind, not even its folder
            shutil.rmtree(target.parent, ignore_errors=True)
