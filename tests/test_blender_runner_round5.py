"""The Blender runner's failures as a user reads them (issue 50): a pass that times out
is not "Blender crashed"; a failure in the script names the log it keeps; an
interrupted session leaves no log. A fake script speaks the runner's protocol, so no
Blender is needed."""

from __future__ import annotations

import os
import signal

import pytest

from zcomp_cli.blender import runner

FAKE = """
import sys, threading, time
from zcomp_cli.blender.runner import serve_job_file

def process(item, common):
    if item.get("hang"):
        threading.Event().wait()
    if item.get("fail"):
        raise ValueError("the scene's mesh is empty")
    return {}

sys.exit(serve_job_file(sys.argv[1], process, started=time.monotonic(), blender_version="fake"))
"""


@pytest.fixture
def fake(tmp_path, monkeypatch):
    p = tmp_path / "fake_script.py"
    p.write_text(FAKE)
    monkeypatch.setattr(runner, "script_path", lambda name: p)
    return "fake_script.py"


def test_a_pass_over_its_time_limit_is_named_a_timeout(fake):
    res = runner.run_blender_batch(fake, [{"id": "a", "hang": True}, {"id": "b"}], item_timeout_s=1.0)
    assert res.results["b"]["event"] == "done"
    err = res.results["a"]["error"]
    assert "took longer than 1 s" in err and "crashed" not in err, err
    assert str(res.log_path) in err and res.log_path.is_file()  # kept, and named
    res.log_path.unlink()


def test_a_failure_in_the_script_names_the_log_it_keeps(fake):
    res = runner.run_blender_batch(fake, [{"id": "a", "fail": True}, {"id": "b"}])
    err = res.results["a"]["error"]
    assert "the scene's mesh is empty" in err and str(res.log_path) in err, err
    assert res.log_path.is_file()
    res.log_path.unlink()
    with runner.BlenderSession(fake) as s:
        got = s.run([{"id": "c", "fail": True}])
    assert str(s.log_path) in got.results["c"]["error"] and s.log_path.is_file()
    s.log_path.unlink()


def test_an_interrupted_session_leaves_no_log(fake):
    """After SIGTERM (here SIGINT, the same path) the session's log stayed until a
    later composite swept it; the README says an interrupt deletes it."""
    def interrupt_on_start(ev):
        if ev.get("event") == "start":
            os.kill(os.getpid(), signal.SIGINT)

    # Python's own SIGINT handler, whatever the launcher left (a shell's background job
    # starts with SIGINT ignored, and the interrupt would then never come)
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        s = runner.BlenderSession(fake)
        s.run([{"id": "ok"}, {"id": "fine", "fail": True}])  # an earlier failure: the log was to be kept
        with pytest.raises(KeyboardInterrupt):
            s.run([{"id": "a", "hang": True}], on_event=interrupt_on_start)
        s.close()
    finally:
        signal.signal(signal.SIGINT, before)
    assert not s.log_path.exists()
