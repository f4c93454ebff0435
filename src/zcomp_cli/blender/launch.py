"""Start a Blender script as a child that dies with its parent.

    python -m zcomp_cli.blender.launch SCRIPT ARG

The runner (``blender.runner``) starts every script this way. Before the script (and
bpy, which takes a second to load) runs, Linux's parent-death signal is armed
(``prctl(PR_SET_PDEATHSIG, SIGKILL)``): when the zcomp process that started Blender
dies, even by ``kill -9``, Blender is killed instead of rendering on, orphaned, into
work folders that a later run has already swept. Then the script runs as if started
directly (``python SCRIPT ARG``). Elsewhere than Linux the signal is not available; the
parent's pipes closing still ends the script at its next event.
"""

from __future__ import annotations

import os
import runpy
import signal
import sys

PARENT_ENV = "ZCOMP_BLENDER_PARENT"  # the pid of the zcomp process that started this one
PR_SET_PDEATHSIG = 1


def die_with_parent() -> None:
    """Arm the parent-death signal; exit at once if the parent is already gone."""
    parent = os.environ.get(PARENT_ENV)
    if not parent or not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if str(os.getppid()) != parent:  # it died before the signal was armed
        os._exit(1)


def main(argv: list[str]) -> None:
    if len(argv) < 2:
        raise SystemExit("usage: python -m zcomp_cli.blender.launch SCRIPT [ARG ...]")
    die_with_parent()
    script = os.path.abspath(argv[1])
    sys.argv = [script, *argv[2:]]
    sys.path.insert(0, os.path.dirname(script))  # the script's own imports (_bpy_common)
    runpy.run_path(script, run_name="__main__")


if __name__ == "__main__":
    main(sys.argv)
