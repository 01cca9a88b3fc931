"""Atomic output: write to a temporary file beside the target, rename on success.

A failed or interrupted write leaves no partial file behind.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from ..errors import InputError

__all__ = ["atomic_path"]


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path in the target's folder; move it onto ``path`` if the block succeeds.

    The temporary name keeps the target's suffix so that writers which choose the format
    from the file name (trimesh, PIL) work unchanged.

    Examples
    --------
    >>> with atomic_path("/tmp/out.txt") as tmp:
    ...     _ = open(tmp, "w").write("done")
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise InputError(f"{path}: output folder {folder} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=suffix or path.suffix)
    except OSError as e:
        raise InputError(f"{path}: cannot write ({e.strerror or e})") from None
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp makes the file private (0600); give it the mode a plain open() would
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except OSError as e:
        raise InputError(f"{path}: cannot write ({e.strerror or e})") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_json(path, obj, indent: int = 1):
    """Write ``obj`` as JSON to ``path`` atomically (:func:`atomic_path`). Returns ``path``."""
    import json
    from pathlib import Path

    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(obj, indent=indent))
    return path
