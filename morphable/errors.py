"""Errors that reach users as one line (the CLI prints ``str(err)`` and exits non-zero)."""


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
