"""Interrupts as exceptions, and the few places they must wait.

The ``zcomp`` command turns SIGINT, SIGTERM and SIGHUP into :class:`Interrupted` (a
``KeyboardInterrupt``) raised in the main thread (``cli.signals_as_interrupts``), so that
every ``finally`` that cleans up after Ctrl-C also runs after the other two. A few
steps must not be cut in half -- a lock file opened but not yet recorded as ours (it
would stay behind), a temporary file created but not yet owned by the code that
removes it -- so they run under :func:`deferred`: a signal that arrives then is held
and raised when the step ends. (Python runs signal handlers in the main thread, at
its next instruction, whichever thread the system delivered the signal to; so this
works where blocking the signal in one thread would not.)
"""

from __future__ import annotations

import contextlib
import threading

_state = threading.local()  # only the main thread ever defers (handlers run there)
_pending: list[int] = []


class Interrupted(KeyboardInterrupt):
    """SIGINT, SIGTERM or SIGHUP, raised in the main thread like Ctrl-C's
    KeyboardInterrupt; ``signum`` tells which (the exit code is 128 + it)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _depth() -> int:
    return getattr(_state, "depth", 0)


@contextlib.contextmanager
def deferred():
    """Run the block whole: an interrupt that arrives inside it is raised at its end."""
    _state.depth = _depth() + 1
    try:
        yield
    finally:
        _state.depth = _depth() - 1
        if _state.depth == 0 and _pending:
            signum = _pending[0]
            _pending.clear()
            raise Interrupted(signum)


def made_whole(make, undo):
    """``make()`` under :func:`deferred`, its result returned; an interrupt held
    meanwhile is raised as the block ends, before the caller owns what was made, so
    ``undo(result)`` removes it first (a temporary file, a folder)."""
    made = None
    try:
        with deferred():
            made = make()
    except BaseException:
        if made is not None:
            undo(made)
        raise
    return made


def interrupt(signum: int) -> None:
    """What a signal handler does: raise ``Interrupted`` now, or when the current
    :func:`deferred` block ends."""
    if _depth() > 0:
        if not _pending:
            _pending.append(signum)
        return
    raise Interrupted(signum)
