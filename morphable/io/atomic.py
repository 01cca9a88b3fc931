"""Atomic output: write to a temporary file beside the target, rename on success.

A failed or interrupted write leaves no partial file behind.
"""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from ..errors import InputError

__all__ = ["atomic_path", "all_or_nothing"]


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


@contextlib.contextmanager
def all_or_nothing(written: list):
    """Remove every path in ``written`` if the block fails: the files of one result all land or none.

    The block appends each file to ``written`` once it is in place (:func:`atomic_path` makes
    each one whole); a later failure would otherwise leave, say, a mesh without its report,
    which would pass for a finished result.

    Parameters
    ----------
    written : list of str or Path, filled by the block

    Examples
    --------
    >>> import os
    >>> written = []
    >>> try:
    ...     with all_or_nothing(written):
    ...         _ = open("/tmp/part.txt", "w").write("one of two")
    ...         written.append("/tmp/part.txt")
    ...         raise OSError("the second file failed")
    ... except OSError:
    ...     pass
    >>> os.path.exists("/tmp/part.txt")
    False
    """
    try:
        yield written
    except BaseException:
        for p in written:
            Path(p).unlink(missing_ok=True)
        raise


def write_json(path, obj, indent: int = 1):
    """Write ``obj`` as JSON to ``path`` atomically (:func:`atomic_path`). Returns ``path``."""
    import json
    from pathlib import Path

    with atomic_path(path) as tmp:
        Path(tmp).write_text(json.dumps(obj, indent=indent))
    return path
