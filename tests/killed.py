"""Run a command with one of its functions made to kill the process (SIGKILL) as its N-th call
returns: the kill/resume tests' kill at a known point of a run, instead of a race between a
poll of the run's files and the work.

    python tests/killed.py PACKAGE.MODULE:NAME[.ATTR] N COMMAND_MODULE [ARGS...]

wraps ``NAME`` (a function, or ``.ATTR`` of a class: a method) of ``PACKAGE.MODULE``, then
calls ``COMMAND_MODULE.main(ARGS)``. The N-th call's work is done (a fit-batch item's files
are in its temporary folder, a training step has run) and the run has not recorded it.
"""
import functools
import importlib
import os
import signal
import sys


def kill_on_call(fn, n: int):
    """``fn`` that kills this process as its ``n``-th call returns."""
    calls = 0

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        nonlocal calls
        out = fn(*args, **kwargs)
        calls += 1
        if calls == n:
            os.kill(os.getpid(), signal.SIGKILL)
        return out

    return wrapper


def main(argv) -> int:
    target, n, command, *args = argv
    module, _, path = target.partition(":")
    owner = importlib.import_module(module)
    *parents, name = path.split(".")
    for p in parents:
        owner = getattr(owner, p)
    setattr(owner, name, kill_on_call(getattr(owner, name), int(n)))
    return importlib.import_module(command).main(args)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
