"""Run a Blender script over a batch of items in ONE subprocess (BlenderProc's lesson:
bpy never in the main process, one Blender start-up per batch).

Protocol between this module and a script in ``zcomp_cli/blender/scripts/``:

* The script is run as ``python SCRIPT JOB.json`` with the same interpreter (bpy is a
  Python module). ``JOB.json`` is ``{"common": {...}, "items": [{"id": str, ...}, ...]}``.
* The script prints one line per event on stdout, prefixed with ``EVENT_PREFIX`` and
  followed by a JSON object:
  ``{"event": "ready", "startup_s": float}`` once bpy is imported and reset,
  ``{"event": "start", "id": ...}`` before an item,
  ``{"event": "done", "id": ..., "seconds": float, ...}`` after a successful item,
  ``{"event": "error", "id": ..., "error": "message"}`` after a failed item.
  Anything else on stdout/stderr is Blender's chatter, kept in a log file.
* If the process dies (segfault, out of memory) in the middle of an item, that item is
  reported failed ("Blender crashed ...") and a fresh process takes the remaining items,
  so a bad mesh never loses the rest of the batch.
* The child dies with zcomp: it is started through ``zcomp_cli.blender.launch``, which
  arms Linux's parent-death signal before bpy loads, so even ``kill -9`` of zcomp ends
  Blender (it would otherwise go on rendering into folders a later run has swept). An
  interrupted batch (Ctrl-C, SIGTERM, SIGHUP) kills its child at once.
* Blender's log (``/tmp/zcomp-blender-<pid>-*.log`` by default) is deleted when nothing
  went wrong or the batch (or session) was interrupted; a batch with a failed item keeps
  it (the item's error names it, whether the script raised, Blender died, or the item
  passed ``item_timeout_s``, which is said as such) and marks it so (``KEEP_MARK``); the
  log of a killed run is removed by a later run's sweep
  (``pipeline.outguard.sweep_dead_temporaries``).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Callable

from zcomp_cli.errors import RenderError

EVENT_PREFIX = "@@ZCOMP@@ "
LOG_PREFIX = "zcomp-blender-"
TMP_PREFIX = "zcomp-blendertmp-"  # the child's TMPDIR (see _spawn)
# The last line of a log kept on purpose (an item failed and its error names the log):
# a later run's sweep leaves such a log alone.
KEEP_MARK = "[zcomp] log kept: an item failed"


def _temporary_log() -> Path:
    from zcomp_cli.interrupts import made_whole

    def make():
        fd, made = tempfile.mkstemp(prefix=f"{LOG_PREFIX}{os.getpid()}-", suffix=".log")
        os.close(fd)
        return made

    # the pid in the name lets a later run remove it if this process is killed
    return Path(made_whole(make, lambda p: Path(p).unlink(missing_ok=True)))


def _spawn(path: Path, arg: str, **popen_kw) -> subprocess.Popen:
    """Start ``python -m zcomp_cli.blender.launch SCRIPT ARG`` (the script then dies
    with this process: ``launch``).

    The child's temporary folder (``TMPDIR``: Blender makes its session folder
    ``blender_XXXXXX`` there) is ``/tmp/zcomp-blendertmp-<pid>-*``, made here and removed
    by ``_end``: a Blender killed mid-render (``kill -9``, its parent's death) left an
    empty ``/tmp/blender_*`` behind; this one goes when the child ends, or at a later
    run's sweep when zcomp itself was killed (``outguard.sweep_dead_temporaries``)."""
    from zcomp_cli.blender.launch import PARENT_ENV
    from zcomp_cli.interrupts import made_whole

    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    env[PARENT_ENV] = str(os.getpid())
    tmp = made_whole(lambda: tempfile.mkdtemp(prefix=f"{TMP_PREFIX}{os.getpid()}-"),
                     lambda p: shutil.rmtree(p, ignore_errors=True))
    env["TMPDIR"] = env["TMP"] = env["TEMP"] = tmp
    try:
        # -P: no current folder on the child's sys.path (launch puts the script's folder there)
        proc = subprocess.Popen([sys.executable, "-P", "-m", "zcomp_cli.blender.launch", str(path), arg],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace",
                                env=env, bufsize=1, **popen_kw)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    proc.zcomp_tmpdir = tmp
    return proc


def _end(proc: subprocess.Popen, *, kill: bool, timeout_s: float = 60.0) -> None:
    """Wait for ``proc`` (``kill``: kill it first, for an interrupted batch), then
    remove its temporary folder."""
    try:
        if kill and proc.poll() is None:
            with contextlib.suppress(OSError):
                proc.kill()
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    finally:
        tmp = getattr(proc, "zcomp_tmpdir", None)
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)


def _keep_log(log) -> None:
    with contextlib.suppress(OSError, ValueError):
        log.write(f"\n{KEEP_MARK}\n")
        log.flush()


def script_path(name: str) -> Path:
    """Absolute path of ``zcomp_cli/blender/scripts/<name>`` (works installed or editable)."""
    p = Path(str(resources.files("zcomp_cli.blender.scripts").joinpath(name)))
    if not p.is_file():
        raise RenderError(f"Blender script {name!r} not found (looked at {p})")
    return p


@dataclass
class BatchResult:
    """Per-item events of a batch (``done`` or ``error`` event dicts keyed by id),
    Blender start-up seconds per process, and the log file of Blender's output."""

    results: dict[str, dict] = field(default_factory=dict)
    startup_s: list[float] = field(default_factory=list)
    log_path: Path | None = None
    restarts: int = 0
    timed_out: dict[str, float] = field(default_factory=dict)  # item id -> the limit it passed


def _fail_after_death(result, pending, started, log_path, on_event) -> list:
    """A Blender process ended early. If it was working on ``started``, that item crashed
    it: fail it alone and return the rest. If it died before starting any item, Blender
    itself does not start: fail every pending item. Returns the items still to run."""
    def fail(item_id: str, why: str) -> None:
        ev = {"event": "error", "id": item_id, "error": f"{why} (log: {log_path})"}
        result.results[item_id] = ev
        if on_event:
            on_event(ev)

    if started is not None and started not in result.results:
        limit = result.timed_out.get(started)
        fail(started, "Blender crashed while processing this item" if limit is None else
             f"took longer than {limit:g} s (the renderer's item_timeout_s): Blender was stopped")
        return [it for it in pending if str(it["id"]) != started]
    if started is None:
        for it in pending:
            fail(str(it["id"]), "Blender failed to start")
        return []
    return pending


def run_blender_batch(
    script: str,
    items: list[dict],
    *,
    common: dict | None = None,
    on_event: Callable[[dict], None] | None = None,
    log_path: str | Path | None = None,
    item_timeout_s: float = 1800.0,
    max_restarts: int | None = None,
) -> BatchResult:
    """Run ``zcomp_cli/blender/scripts/<script>`` over ``items`` in as few processes as possible.

    Args:
        script: file name inside ``zcomp_cli/blender/scripts/``.
        items: JSON-serialisable dicts, each with a unique string ``"id"``.
        common: settings shared by every item.
        on_event: called with every event dict as it arrives (progress bars).
        log_path: where Blender's own output goes (default: a temporary file).
        item_timeout_s: a single item taking longer kills the process (item failed).
        max_restarts: how many crashed processes to replace (default: one per item).
    Returns:
        A ``BatchResult``; every item id has a ``done`` or ``error`` event.
    """
    ids = [str(it["id"]) for it in items]
    if len(set(ids)) != len(ids):
        raise ValueError("item ids must be unique")
    path = script_path(script)
    result = BatchResult()
    temporary_log = log_path is None
    pending = list(items)
    max_restarts = len(items) if max_restarts is None else max_restarts
    clean = False
    result.log_path = _temporary_log() if log_path is None else Path(log_path)
    try:
        with open(result.log_path, "a", encoding="utf-8", errors="replace") as log:
            while pending:
                started = _run_one_process(path, pending, common or {}, on_event, log, result, item_timeout_s)
                pending = [it for it in pending if str(it["id"]) not in result.results]
                if not pending:
                    break
                # The process ended early: the item it was working on crashed it.
                pending = _fail_after_death(result, pending, started, result.log_path, on_event)
                result.restarts += 1
                if result.restarts > max_restarts and pending:
                    for it in pending:
                        ev = {"event": "error", "id": str(it["id"]), "error": "too many Blender crashes"}
                        result.results[str(it["id"])] = ev
                    pending = []
            clean = result.restarts == 0 and all(ev.get("event") == "done" for ev in result.results.values())
            if not clean:
                _keep_log(log)  # the failed items' errors name it
    except BaseException:
        clean = True  # interrupted: nobody will read the log either
        raise
    finally:
        if temporary_log and clean:  # nothing went wrong: nobody will read the log
            with contextlib.suppress(OSError):
                result.log_path.unlink()
    return result


def _run_one_process(path, items, common, on_event, log, result, item_timeout_s) -> str | None:
    """Run one Blender process over ``items``; return the id of the item in progress
    when it ended (None if none started)."""
    # The pid in the name lets a later run remove it if this process is killed.
    with tempfile.TemporaryDirectory(prefix=f"zcomp-job-{os.getpid()}-") as tmpdir:
        job = Path(tmpdir) / "job.json"
        job.write_text(json.dumps({"common": common, "items": items}))
        proc = _spawn(path, str(job), stdin=subprocess.DEVNULL)
        try:
            current = _pump(proc, on_event, log, result, item_timeout_s)
        except BaseException:  # interrupted (Ctrl-C, SIGTERM): Blender stops now
            _end(proc, kill=True)
            raise
        _end(proc, kill=False)
        if proc.returncode not in (0, None):
            log.write(f"\n[zcomp] Blender process exited with code {proc.returncode}\n")
        return current


def _pump(proc, on_event, log, result, item_timeout_s, *, until_batch_done: bool = False) -> str | None:
    """Read ``proc``'s events into ``result`` until EOF (or, for a session, the
    ``batch_done`` event). Returns the id of the item in progress when the stream ended
    (None if none): a process that ends in the middle of an item crashed on it."""
    current: str | None = None
    # A watchdog, not the reading loop, enforces the per-item limit: a hung Blender
    # prints nothing, so a check between lines would never run.
    state = {"current": None, "t": time.monotonic(), "stop": False}

    def _watchdog():
        while not state["stop"] and proc.poll() is None:
            if state["current"] is not None and time.monotonic() - state["t"] > item_timeout_s:
                log.write(f"\n[zcomp] item {state['current']} exceeded {item_timeout_s:.0f} s: killing Blender\n")
                result.timed_out[state["current"]] = float(item_timeout_s)
                proc.kill()
                return
            time.sleep(0.5)

    watchdog = threading.Thread(target=_watchdog, daemon=True)
    watchdog.start()
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if not line.startswith(EVENT_PREFIX):
                log.write(line)
                continue
            try:
                ev = json.loads(line[len(EVENT_PREFIX):])
            except json.JSONDecodeError:
                log.write(line)
                continue
            kind = ev.get("event")
            if kind == "ready":
                result.startup_s.append(float(ev.get("startup_s", float("nan"))))
            elif kind == "start":
                current = str(ev.get("id"))
                state["t"] = time.monotonic()
                state["current"] = current
            elif kind in ("done", "error"):
                if kind == "error":  # the log is kept (the batch failed): the reason names it
                    ev["error"] = f"{ev.get('error', 'failed')} (Blender's log: {getattr(log, 'name', '?')})"
                result.results[str(ev.get("id"))] = ev
                current = None
                state["current"] = None
            elif kind == "batch_done" and until_batch_done:
                return None
            if on_event and kind != "batch_done":
                on_event(ev)
    finally:
        state["stop"] = True
    return current


class BlenderSession:
    """One Blender process kept for many batches (a Ray worker renders unit after unit
    without paying Blender's start-up, and the script keeps its imported mesh and
    Cycles scene between batches). The script is run as ``python SCRIPT -`` and reads
    one ``{"common", "items"}`` JSON object per line on stdin, answering each with the
    usual events and a final ``{"event": "batch_done"}``; it exits when stdin closes.
    A process that dies is replaced, with the same crash rules as
    ``run_blender_batch``."""

    def __init__(self, script: str, *, log_path: str | Path | None = None, item_timeout_s: float = 1800.0):
        self.path = script_path(script)
        self._temporary_log = log_path is None
        self.log_path = _temporary_log() if log_path is None else Path(log_path)
        self._troubled = False  # an item failed or a process died: keep the log
        self.item_timeout_s = item_timeout_s
        self.proc: subprocess.Popen | None = None
        self.starts = 0

    def _start(self) -> None:
        self._log = open(self.log_path, "a", encoding="utf-8", errors="replace")
        self.proc = _spawn(self.path, "-", stdin=subprocess.PIPE)
        self.starts += 1

    def run(self, items: list[dict], *, common: dict | None = None,
            on_event: Callable[[dict], None] | None = None) -> BatchResult:
        """Render ``items`` (as ``run_blender_batch``) in the session's process."""
        ids = [str(it["id"]) for it in items]
        if len(set(ids)) != len(ids):
            raise ValueError("item ids must be unique")
        result = BatchResult(log_path=self.log_path)
        pending = list(items)
        while pending:
            fresh = self.proc is None or self.proc.poll() is not None
            if fresh:
                if self.proc is not None:  # it died while idle
                    self._troubled = True
                    self._reap()
                self._start()
            try:
                self.proc.stdin.write(json.dumps({"common": common or {}, "items": pending}) + "\n")
                self.proc.stdin.flush()
                started = _pump(self.proc, on_event, self._log, result, self.item_timeout_s, until_batch_done=True)
            except (BrokenPipeError, OSError):
                started = None
            except BaseException:  # interrupted: Blender stops now, and nobody will read its log
                self._reap(kill=True)
                if self._temporary_log:
                    self.log_path.unlink(missing_ok=True)
                    self._troubled = False
                raise
            pending = [it for it in pending if str(it["id"]) not in result.results]
            if not pending:
                break
            # the process ended before batch_done: it crashed on `started`
            self._troubled = True
            self._reap()
            if started is None and not fresh:
                continue  # it had died while idle: a fresh one takes the batch
            pending = _fail_after_death(result, pending, started, self.log_path, on_event)
            result.restarts += 1
        if any(ev.get("event") != "done" for ev in result.results.values()):
            self._troubled = True
        return result

    def _reap(self, *, kill: bool = False) -> None:
        if self.proc is not None:
            _end(self.proc, kill=kill)
            self._log.write(f"\n[zcomp] Blender process exited with code {self.proc.returncode}\n")
            if self._troubled and not kill:
                _keep_log(self._log)
            self._log.close()
        self.proc = None

    def close(self) -> None:
        """End the process (it exits on the end of its stdin)."""
        if self.proc is not None and self.proc.poll() is None:
            try:
                self.proc.stdin.close()
            except OSError:
                pass
        self._reap()
        if self._temporary_log and not self._troubled:  # nobody will read it
            self.log_path.unlink(missing_ok=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def emit(event: dict) -> None:
    """For scripts: print one protocol event (flushes)."""
    sys.stdout.write(EVENT_PREFIX + json.dumps(event) + "\n")
    sys.stdout.flush()


def serve_job_file(job_path: str, process: Callable[[dict, dict], dict], *, started: float,
                   blender_version: str) -> int:
    """For scripts: the whole script side of the protocol. Reads JOB.json, announces
    readiness (with the start-up time since ``started``, a ``time.monotonic()`` taken
    before ``import bpy``), then runs ``process(item, common) -> dict`` per item,
    emitting start/done/error events. An exception fails that item only."""
    if job_path == "-":  # a BlenderSession: one batch per stdin line, until EOF
        emit({"event": "ready", "startup_s": time.monotonic() - started, "blender_version": blender_version})
        for line in sys.stdin:
            if line.strip():
                job = json.loads(line)
                _serve_items(job.get("common", {}), job["items"], process, blender_version)
                emit({"event": "batch_done"})
        return 0
    with open(job_path) as f:
        job = json.load(f)
    emit({"event": "ready", "startup_s": time.monotonic() - started, "blender_version": blender_version})
    _serve_items(job.get("common", {}), job["items"], process, blender_version)
    return 0


def _serve_items(common: dict, items: list[dict], process, blender_version: str) -> None:
    import traceback

    for item in items:
        iid = str(item["id"])
        emit({"event": "start", "id": iid})
        t = time.monotonic()
        try:
            info = process(item, common)
        except Exception as exc:  # one bad item must not stop the batch
            traceback.print_exc()
            emit({"event": "error", "id": iid, "error": f"{type(exc).__name__}: {str(exc).strip()}"})
            continue
        emit({"event": "done", "id": iid, "seconds": time.monotonic() - t,
              "blender_version": blender_version, **info})
