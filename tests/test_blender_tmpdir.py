"""Blender's session folder (``blender_XXXXXX``) lives in a temporary folder zcomp owns
and removes: a Blender killed mid-render left an empty ``/tmp/blender_*`` (issue 39)."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from zcomp_cli.blender.runner import TMP_PREFIX, _end, _spawn
from zcomp_cli.pipeline.outguard import sweep_dead_temporaries

SCRIPT = """
import time
import bpy
print(bpy.app.tempdir, flush=True)
time.sleep(120)
"""


@pytest.mark.blender
def test_a_killed_blender_leaves_no_session_folder(tmp_path):
    script = tmp_path / "tmpdir_probe.py"
    script.write_text(SCRIPT)
    proc = _spawn(script, "-", stdin=subprocess.DEVNULL)
    mine = Path(proc.zcomp_tmpdir)
    try:
        line = proc.stdout.readline().strip()
        session = Path(line)
        assert session.is_dir() and session.name.startswith("blender_")
        assert mine in session.parents and mine.name.startswith(TMP_PREFIX)
    finally:
        _end(proc, kill=True)  # as for an item over its time limit, or an interrupt
    assert proc.returncode != 0 and not mine.exists()


def test_the_folders_of_a_killed_zcomp_are_swept():
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    left = Path(tempfile.gettempdir()) / f"{TMP_PREFIX}{dead.pid}-x1"
    (left / "blender_abc").mkdir(parents=True)
    try:
        sweep_dead_temporaries()
        assert not left.exists()
    finally:
        import shutil

        shutil.rmtree(left, ignore_errors=True)
