"""An interrupt held by ``interrupts.deferred`` while a temporary file, a Blender log
or a lock file is made is raised as the block ends, before the code that owns the new
thing could remove it: it must not stay (the signal fuzz found a `.report.<pid>-*.tmp.json`
after a SIGTERM)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from zcomp_cli import interrupts


def _interrupting(real):
    def made(*a, **k):
        out = real(*a, **k)
        interrupts.interrupt(signal.SIGTERM)  # inside deferred(): held until the block ends
        return out
    return made


def test_an_atomic_write_interrupted_while_its_temporary_is_made_leaves_nothing(tmp_path, monkeypatch):
    from zcomp_cli.imageio import write_text_atomic

    monkeypatch.setattr(tempfile, "mkstemp", _interrupting(tempfile.mkstemp))
    with pytest.raises(interrupts.Interrupted):
        write_text_atomic(tmp_path / "report.json", "{}")
    assert list(tmp_path.iterdir()) == []


def test_a_blender_log_interrupted_while_it_is_made_leaves_nothing(monkeypatch):
    from zcomp_cli.blender import runner

    real, made = tempfile.mkstemp, []

    def mkstemp(*a, **k):
        out = real(*a, **k)
        made.append(out[1])
        interrupts.interrupt(signal.SIGTERM)
        return out

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    with pytest.raises(interrupts.Interrupted):
        runner._temporary_log()
    assert made and not os.path.exists(made[0])


def test_a_lock_taken_while_an_interrupt_is_held_is_given_back(tmp_path, monkeypatch):
    from zcomp_cli.pipeline.outguard import _FileLock

    lock = _FileLock(tmp_path / ".zcomp-run-1.lock", {"pid": os.getpid()})
    monkeypatch.setattr(lock, "_try_acquire", _interrupting(lock._try_acquire))
    with pytest.raises(interrupts.Interrupted):
        lock.try_acquire()
    assert lock.fd is None and not (tmp_path / ".zcomp-run-1.lock").exists()


def test_once_the_command_is_over_no_stop_signal_changes_its_exit():
    """After the command (outputs and summary written), SIGINT is ignored like SIGTERM
    and SIGHUP: a SIGINT in the tear-down killed a finished run with -2."""
    code = ("import signal\nfrom zcomp_cli.cli import _ignore_signals_from_now as f\nf()\n"
            "print(all(signal.getsignal(s) is signal.SIG_IGN for s in "
            "(signal.SIGINT, signal.SIGTERM, signal.SIGHUP)))")
    src = Path(__file__).resolve().parents[1] / "src"
    env = dict(os.environ, PYTHONPATH=str(src))
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "True", r.stdout + r.stderr
