"""Errors that reach users as one line (the CLI and the ``python -m`` scripts print
``str(err)`` and exit non-zero)."""


class MorphableError(Exception):
    """Base class for the errors the toolkit raises on bad input or bad state."""


class InputError(MorphableError, ValueError):
    """A file or an argument cannot be used; the message names it and the problem.

    Examples
    --------
    >>> raise InputError("model.bin: truncated at byte 12 (expected 41376 more)")
    Traceback (most recent call last):
    ...
    morphable.errors.InputError: model.bin: truncated at byte 12 (expected 41376 more)
    """


class FitError(MorphableError, RuntimeError):
    """A fit cannot be made from the given data (too few or degenerate landmarks...)."""


def one_line_errors(prog: str):
    """Decorator for the ``main(argv=None) -> int`` of a ``python -m`` script: a
    :class:`MorphableError` reaches the user as the one line ``prog: error: message`` on
    stderr and exit status 2, never as a traceback.

    Examples
    --------
    >>> @one_line_errors("python -m demo")
    ... def main(argv=None):
    ...     raise InputError("in.obj: empty mesh")
    >>> import contextlib, io
    >>> err = io.StringIO()
    >>> with contextlib.redirect_stderr(err):
    ...     code = main([])
    >>> code, err.getvalue()
    (2, 'python -m demo: error: in.obj: empty mesh\\n')
    """
    import functools
    import sys

    def wrap(main):
        @functools.wraps(main)
        def run(argv=None):
            try:
                return main(argv)
            except MorphableError as e:
                print(f"{prog}: error: {e}", file=sys.stderr)
                return 2
        return run
    return wrap
