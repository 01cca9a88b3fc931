"""What our commands print on stderr: their own lines, and library chatter only when asked.

The commands (``morphable``, ``python -m evaluation.…``, ``python -m neural.…``) print
results on stdout and their own messages (progress, warnings, the one-line error) on stderr.
Libraries speak too: matplotlib announces "generated new fontManager" the first time it runs
on a machine, VTK logs its fall-back to off-screen rendering, open3d prints "[Open3D WARNING]"
lines, torch and others raise Python warnings. On a fresh machine that turned a one-line
error into two. :func:`configure` sends all of it through ``logging``, and the user's
verbosity decides what reaches stderr:

=============  ========================  =========================================
verbosity      our loggers               libraries' loggers, Python warnings, VTK,
                                         open3d
=============  ========================  =========================================
-1 (``-q``)    warnings and errors       nothing (VTK's and open3d's own errors)
0 (default)    info and up               nothing (VTK's and open3d's own errors)
1 (``-v``)     info and up               warnings and up
2 (``-vv``)    debug and up              everything (debug included)
=============  ========================  =========================================

"Our loggers" are those under ``morphable``, ``neural`` and ``evaluation``. Native libraries
that write to stderr themselves get their own verbosity set when we import them
(:func:`import_open3d`, :func:`quiet_vtk`). Programs that use the library without
:func:`configure` keep Python's defaults.
"""
from __future__ import annotations

import logging
import sys

__all__ = ["configure", "add_verbosity_arguments", "verbosity", "library_level",
           "import_open3d", "quiet_vtk", "OWN_LOGGERS"]

OWN_LOGGERS = ("morphable", "neural", "evaluation")
"""Logger name prefixes of this project: they speak at the default verbosity."""

_SILENT = logging.CRITICAL + 10
_library_level = None          # None until configure(): library defaults stay as they are


class _Filter(logging.Filter):
    def __init__(self, own_level: int, library: int):
        super().__init__()
        self.own_level, self.library = own_level, library

    def filter(self, record: logging.LogRecord) -> bool:
        own = record.name.split(".")[0] in OWN_LOGGERS
        return record.levelno >= (self.own_level if own else self.library)


def configure(verbosity: int = 0, stream=None) -> None:
    """Route messages for a command run at ``verbosity`` (-1 quiet, 0 default, 1 ``-v``,
    2 ``-vv``; see the module docstring) to ``stream`` (default stderr) as
    ``LEVEL: message`` lines. Replaces the handler of an earlier call, so that a process
    that runs several commands (tests) configures each anew."""
    global _library_level
    own = logging.WARNING if verbosity < 0 else logging.INFO if verbosity < 2 else logging.DEBUG
    _library_level = (_SILENT if verbosity <= 0 else logging.WARNING if verbosity == 1
                      else logging.DEBUG)
    root = logging.getLogger()
    for h in list(root.handlers):
        if getattr(h, "_morphable", False):
            root.removeHandler(h)
    handler = logging.StreamHandler(stream if stream is not None else sys.stderr)
    handler._morphable = True
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    handler.addFilter(_Filter(own, _library_level))
    root.addHandler(handler)
    root.setLevel(min(own, _library_level))
    for name in OWN_LOGGERS:
        logging.getLogger(name).setLevel(own)
    # Python warnings (torch's, numpy's...) become records of the "py.warnings" logger
    logging.captureWarnings(True)


def add_verbosity_arguments(parser, defaults: bool = True) -> None:
    """``-q/--quiet`` and ``-v/--verbose`` (repeatable) on an argparse parser: the options
    every command of the project takes; :func:`verbosity` reads them back.

    ``defaults=False`` is for the subcommands of a parser that has them already
    (``morphable fit ... -q``): unset there, they leave the main parser's values alone (a
    subparser's defaults would overwrite ``morphable -q fit``).
    """
    import argparse

    parser.add_argument("-q", "--quiet", action="store_true",
                        default=False if defaults else argparse.SUPPRESS,
                        help="no progress bars, warnings only")
    parser.add_argument("-v", "--verbose", action="count",
                        default=0 if defaults else argparse.SUPPRESS,
                        help="also the libraries' messages (-v warnings, -vv everything)")


def verbosity(args) -> int:
    """The verbosity of parsed :func:`add_verbosity_arguments`: -1 quiet, else the count of
    ``-v``."""
    return -1 if args.quiet else args.verbose


def library_level() -> int | None:
    """The logging level libraries may speak at after :func:`configure`, None before."""
    return _library_level


def import_open3d():
    """``import open3d`` with its own console verbosity set from :func:`library_level`
    (open3d prints to stderr itself, not through logging)."""
    import open3d as o3d

    if _library_level is not None:
        levels = o3d.utility.VerbosityLevel
        o3d.utility.set_verbosity_level(
            levels.Debug if _library_level <= logging.DEBUG else
            levels.Warning if _library_level <= logging.WARNING else levels.Error)
    return o3d


def quiet_vtk() -> None:
    """VTK's stderr log at errors only, or at warnings under ``-v`` (VTK tries X first and
    warns before it falls back to off-screen EGL/OSMesa)."""
    from vtkmodules.vtkCommonCore import vtkLogger

    verbose = _library_level is not None and _library_level <= logging.WARNING
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_WARNING if verbose
                                 else vtkLogger.VERBOSITY_ERROR)
