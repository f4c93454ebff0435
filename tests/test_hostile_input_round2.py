"""Hostile input, round 2 (issue 30): one test per attack of the issue's table, through
the real CLI, each failing before its fix.

Mesh-free project (``hostile_project``: a floor scene given as maps, a sphere bundle
and a 2D card), naive or a cheap physical renderer, so each test takes a second or two;
the tests that need Blender are marked ``blender``.
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from hostile_project import base_manifest, default_signals, make_project, run_composite, textured_quad, write_manifest
from zcomp_cli.cli import cli
from zcomp_cli.imageio import write_exr, write_png

SRC = Path(__file__).resolve().parents[1] / "src"
CHEAP_PHYSICAL = {"name": "physical", "march_steps": 4, "estimate_march_steps": 4, "n_light_candidates": 16,
                  "cone_samples": 2, "max_fit_pixels": 500}


@pytest.fixture
def project(tmp_path):
    make_project(tmp_path)
    return tmp_path


_write = write_manifest


def _composite(manifest, out, *extra):
    r = run_composite(manifest, out, *extra)
    assert "Traceback" not in r.output, r.output
    return r


def _this_run(out: Path) -> dict[str, str | None]:
    """What the last run did to each job: done, skipped, failed (None: not selected)."""
    return {j["name"]: j["this_run"] for j in json.loads((out / "summary.json").read_text())["jobs"]}


def _status(out, *extra) -> tuple[int, dict]:
    r = CliRunner().invoke(cli, ["status", str(out), "--json", *map(str, extra)])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    return r.exit_code, json.loads(r.output)


def _env():
    return dict(os.environ, PYTHONPATH=str(SRC))


def _zcomp(*args) -> list[str]:
    return [sys.executable, "-m", "zcomp_cli", *map(str, args)]


def _litter(out: Path) -> list[Path]:
    return [p for p in out.rglob("*") if p.name.startswith(".zcomp-") or ".tmp" in p.name]


# ------------------------------------------------------------------ 1. every input in the fingerprint
def _two_scene_light_manifest(project: Path) -> dict:
    """Scene ``room`` lit by a probe file, scene ``hall`` (the same maps) by a sun;
    one ball job in room, a ball and a card job in hall."""
    probe = np.full((8, 16, 3), 0.2, np.float32)
    probe[1:3, 10:12] = 40.0  # a sun up and to the right
    write_exr(project / "probe.exr", probe)
    doc = base_manifest()
    doc["defaults"]["renderer"] = dict(CHEAP_PHYSICAL)
    room = doc["scenes"]["room"]
    doc["scenes"]["hall"] = {**room, "light": {"azimuth_deg": 30, "elevation_deg": 45, "strength": 3}}
    room["light"] = {"type": "probe", "hdr": "probe.exr", "rotation_deg": 0}
    ball, card = doc["jobs"]
    doc["jobs"] = [{**ball, "output": "room_ball"}, {**ball, "scene": "hall", "output": "hall_ball"},
                   {**card, "scene": "hall", "output": "hall_card"}]
    return doc


def test_a_changed_light_redoes_exactly_its_scene(project):
    """Known light (issue "known light"): the scene's parsed light and its probe's
    content are in the fingerprint; --resume refuses stale outputs, --redo-changed
    redoes exactly that scene's jobs."""
    doc = _two_scene_light_manifest(project)
    m = _write(project, doc)
    out = project / "out"
    assert _composite(m, out).exit_code == 0
    assert _composite(m, out, "--resume").exit_code == 0
    assert set(_this_run(out).values()) == {"skipped"}

    doc["scenes"]["hall"]["light"]["strength"] = 1.5  # only hall's light
    _write(project, doc)
    r = _composite(m, out, "--resume")
    assert r.exit_code == 2 and "hall_ball" in r.output and "hall_card" in r.output and "room_ball" not in r.output
    assert _composite(m, out, "--resume", "--redo-changed").exit_code == 0
    assert _this_run(out) == {"room_ball": "skipped", "hall_ball": "done", "hall_card": "done"}

    probe = np.full((8, 16, 3), 0.2, np.float32)  # only the probe file's content
    probe[1:3, 2:4] = 40.0
    write_exr(project / "probe.exr", probe)
    r = _composite(m, out, "--resume")
    assert r.exit_code == 2 and "room_ball" in r.output and "hall_" not in r.output
    assert _composite(m, out, "--resume", "--redo-changed").exit_code == 0
    assert _this_run(out) == {"room_ball": "done", "hall_ball": "skipped", "hall_card": "skipped"}


def test_fingerprint_hashes_the_light_and_scene_settings_generically(project):
    """New light types and keys (lamps, lists mixing a probe with lamps, ``convention``)
    and new scene-level settings are covered without a hand-kept list."""
    from zcomp_cli.pipeline.fingerprint import job_fingerprint
    from zcomp_cli.pipeline.manifest import load_manifest

    m = load_manifest(_write(project, _two_scene_light_manifest(project)))
    job = m.jobs[0]  # room: the probe
    spec = m.defaults.renderer

    def fp():
        return job_fingerprint(m, job, spec, m.defaults.samples)

    import dataclasses

    from zcomp_cli.scene.lightparams import LampParams, Param

    base = fp()
    room = m.scenes["room"]
    lamp = LampParams(position=Param.given((0.0, 1.0, -2.0)), power=Param.given(5.0))
    room.light = dataclasses.replace(room.light, lamps=(lamp,))
    mixed = fp()
    assert mixed != base
    room.light = dataclasses.replace(room.light, lamps=(dataclasses.replace(lamp, power=Param.given(6.0)),))
    assert fp() != mixed
    room.light = dataclasses.replace(room.light, probe=dataclasses.replace(room.light.probe, convention="blender"))
    assert fp() not in (base, mixed)
    before = fp()
    write_exr(project / "probe.exr", np.ones((8, 16, 3), np.float32))  # the probe inside the list
    assert fp() != before
    before = fp()
    room.pitch_deg = -12.0  # a scene-level setting the manifest may gain
    assert fp() != before
    # names, lines and the evaluation reference change no pixel
    before = fp()
    job.line, job.index, room.name = 99, 7, "renamed"
    assert fp() == before


def test_fingerprint_covers_mesh_side_files(project):
    from zcomp_cli.pipeline.fingerprint import job_fingerprint
    from zcomp_cli.pipeline.manifest import load_manifest

    textured_quad(project / "objects/quad")
    (project / "objects/box.bin").write_bytes(b"\0" * 48)
    (project / "objects/box.gltf").write_text(json.dumps({
        "asset": {"version": "2.0"}, "buffers": [{"uri": "box.bin", "byteLength": 48}]}))
    doc = base_manifest()
    doc["objects"]["quad"] = {"mesh": "objects/quad/quad.obj"}
    doc["objects"]["box"] = {"mesh": "objects/box.gltf"}
    doc["jobs"] = [{"scene": "room", "object": o, "pose": {"position": [0, -1.2, -3]}} for o in ("quad", "box")]
    m = load_manifest(_write(project, doc))

    def fps():
        return [job_fingerprint(m, j, m.defaults.renderer, m.defaults.samples) for j in m.jobs]

    a = fps()
    write_png(project / "objects/quad/tex.png", np.zeros((8, 8, 3), np.float32))
    b = fps()
    assert b[0] != a[0] and b[1] == a[1]
    (project / "objects/quad/quad.mtl").write_text("newmtl m\nKd 0.5 0.5 0.5\nmap_Kd tex.png\n")
    c = fps()
    assert c[0] != b[0]
    (project / "objects/box.bin").write_bytes(b"\1" * 48)
    d = fps()
    assert d[1] != c[1] and d[0] == c[0]


@pytest.mark.blender
@pytest.mark.slow
def test_resume_redoes_a_mesh_job_whose_texture_changed(project):
    pytest.importorskip("bpy")
    textured_quad(project / "objects/quad")
    doc = base_manifest()
    doc["defaults"]["samples"] = 2
    doc["objects"]["quad"] = {"mesh": "objects/quad/quad.obj"}
    doc["jobs"] = [{"scene": "room", "object": "quad", "pose": {"position": [0, -1.2, -3], "height": 0.6},
                    "output": "quad"}, {**doc["jobs"][0], "output": "ball"}]
    m = _write(project, doc)
    out = project / "out"
    assert _composite(m, out, "--cache-dir", project / "cache").exit_code == 0
    write_png(project / "objects/quad/tex.png", np.full((8, 8, 3), 0.9, np.float32))
    r = _composite(m, out, "--resume", "--cache-dir", project / "cache")
    assert r.exit_code == 2 and "quad" in r.output, r.output  # before: skipped, stale
    r = _composite(m, out, "--resume", "--redo-changed", "--cache-dir", project / "cache")
    assert r.exit_code == 0, r.output
    assert _this_run(out) == {"quad": "done", "ball": "skipped"}


# ------------------------------------------------------------------ 2. any job count
def test_many_jobs_under_a_small_open_file_limit(project):
    """Each job's lock used to stay open for the whole run: 150 jobs under
    ``ulimit -n 64`` died with 'Too many open files' before any job ran."""
    doc = base_manifest()
    doc["jobs"] = [{"scene": "room", "object": "card", "output": f"j{i:03d}",
                    "placement": {"pixel": [8 + i % 16, 18], "height": 0.3}} for i in range(150)]
    m = _write(project, doc)

    def limit():
        resource.setrlimit(resource.RLIMIT_NOFILE, (64, 64))

    r = subprocess.run(_zcomp("-q", "composite", m, "--out", project / "out"), env=_env(), preexec_fn=limit,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "Traceback" not in r.stderr
    assert json.loads((project / "out/summary.json").read_text())["done"] == 150


# ------------------------------------------------------------------ 3. memory flat in the scenes
def test_each_scene_is_freed_after_its_last_job(tmp_path, monkeypatch):
    """12 jobs over 6 scenes, taken in turn in the manifest: a scene's maps used to stay
    in memory until the batch ended (7.7 MB a scene at 512x384)."""
    import gc
    import weakref

    import zcomp_cli.pipeline.job as job_mod
    import zcomp_cli.pipeline.scene as scene_mod
    from zcomp_cli.testing import write_floor_batch

    manifest = write_floor_batch(tmp_path / "b", 12, n_scenes=6, size=(32, 24), renderer="naive")
    alive: list = []
    peak = [0]
    load, prepare = scene_mod.load_scene, job_mod.prepare_job

    def counted_load(*a, **k):
        sc = load(*a, **k)
        alive.append(weakref.ref(sc))
        return sc

    def watched_prepare(*a, **k):
        gc.collect()
        peak[0] = max(peak[0], sum(1 for r in alive if r() is not None))
        return prepare(*a, **k)

    monkeypatch.setattr(scene_mod, "load_scene", counted_load)
    monkeypatch.setattr(job_mod, "prepare_job", watched_prepare)
    assert _composite(manifest, tmp_path / "out").exit_code == 0
    assert len(alive) == 6, "each scene loaded once"
    assert peak[0] <= 1, f"{peak[0]} scenes in memory at once"


# ------------------------------------------------------------------ 4. signals
def _long_batch(project: Path, n: int = 40) -> Path:
    make_project(project, width=64, height=48)
    doc = base_manifest(64, 48)
    doc["defaults"]["renderer"] = dict(CHEAP_PHYSICAL, march_steps=16)
    doc["jobs"] = [{"scene": "room", "object": "ball" if i % 2 else "card", "seed": i, "output": f"job{i:02d}",
                    **({"pose": {"position": [0, -1.2, -3]}} if i % 2 else
                       {"placement": {"pixel": [10 + i, 36], "height": 0.3}})} for i in range(n)]
    return _write(project, doc)


def _wait_for_reports(out: Path, n: int, proc, timeout: float = 120) -> None:
    t = time.monotonic()
    while len(list(out.glob("*/report.json"))) < n:
        assert proc.poll() is None, "the run ended before it could be signalled"
        assert time.monotonic() - t < timeout
        time.sleep(0.05)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_clean_up_like_ctrl_c(tmp_path, sig):
    m = _long_batch(tmp_path)
    out = tmp_path / "out"
    p = subprocess.Popen(_zcomp("-q", "composite", m, "--out", out), env=_env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, preexec_fn=default_signals)
    _wait_for_reports(out, 3, p)
    p.send_signal(sig)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 128 + sig, err
    assert "Traceback" not in err
    summary = json.loads((out / "summary.json").read_text())
    done = sorted(d.parent.name for d in out.glob("*/report.json"))
    assert summary["done"] == len(done) >= 3, "the summary must say what is on disk"
    assert sorted(j["name"] for j in summary["jobs"] if j["status"] == "done") == done
    assert not _litter(out), _litter(out)
    r = subprocess.run(_zcomp("-q", "composite", m, "--out", out, "--resume"), env=_env(), capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "summary.json").read_text())["done"] == 40


def test_nohup_keeps_ignoring_hangups(tmp_path):
    """``nohup zcomp ...`` ignores SIGHUP: zcomp must not turn it into an interrupt."""
    m = _long_batch(tmp_path, n=12)
    out = tmp_path / "out"

    def ignore_hup():
        signal.signal(signal.SIGHUP, signal.SIG_IGN)

    p = subprocess.Popen(_zcomp("-q", "composite", m, "--out", out), env=_env(), preexec_fn=ignore_hup,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_reports(out, 1, p)
    p.send_signal(signal.SIGHUP)
    _, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
    assert json.loads((out / "summary.json").read_text())["done"] == 12


SLEEPER = """import json, os, sys, time
from zcomp_cli.blender.runner import EVENT_PREFIX
print(EVENT_PREFIX + json.dumps({"event": "ready", "startup_s": 0}), flush=True)
print(EVENT_PREFIX + json.dumps({"event": "start", "id": "a", "pid": os.getpid()}), flush=True)
time.sleep(120)
"""

HARNESS = """import contextlib, sys
from pathlib import Path
import zcomp_cli.blender.runner as runner
try:
    from zcomp_cli.cli import signals_as_interrupts  # what `zcomp` runs a command in
except ImportError:  # (before issue 30)
    signals_as_interrupts = contextlib.nullcontext
runner.script_path = lambda name: Path(sys.argv[1])
def on_event(ev):
    if ev.get("event") == "start":
        print(ev["pid"], flush=True)
with signals_as_interrupts():
    runner.run_blender_batch("sleeper.py", [{"id": "a"}], on_event=on_event)
"""


def _gone(pid: int, timeout: float = 10.0) -> bool:
    t = time.monotonic()
    while time.monotonic() - t < timeout:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split(") ", 1)[1].startswith("Z"):  # a zombie is dead
                    return True
        except FileNotFoundError:
            return True
        time.sleep(0.05)
    return False


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_the_blender_child_dies_with_its_parent(tmp_path, sig):
    """The Blender child used to be orphaned and to keep rendering (also after SIGKILL
    of zcomp), re-creating its work folder after the next run's sweep."""
    (tmp_path / "sleeper.py").write_text(SLEEPER)
    p = subprocess.Popen([sys.executable, "-c", HARNESS, str(tmp_path / "sleeper.py")], env=_env(),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=default_signals)
    child = int(p.stdout.readline())
    try:
        p.send_signal(sig)
        p.wait(timeout=30)
        assert _gone(child), "Blender outlived zcomp"
    finally:
        with __import__("contextlib").suppress(ProcessLookupError):
            os.kill(child, signal.SIGKILL)


def test_logs_of_killed_runs_are_swept_kept_ones_stay(project):
    from zcomp_cli.blender.runner import KEEP_MARK

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    tmp = Path(tempfile.gettempdir())
    litter = tmp / f"zcomp-blender-{dead.pid}-x1.log"
    kept = tmp / f"zcomp-blender-{dead.pid}-x2.log"
    litter.write_text("Blender chatter\n")
    kept.write_text(f"Blender chatter\nitem failed\n\n{KEEP_MARK}\n")
    try:
        assert _composite(project / "jobs.yaml", project / "out").exit_code == 0
        assert not litter.exists() and kept.exists()
    finally:
        litter.unlink(missing_ok=True)
        kept.unlink(missing_ok=True)


# ------------------------------------------------------------------ 5. a shared cache
def test_runs_storing_one_cache_entry_at_once(tmp_path):
    """``cache.store`` could rmtree another run's entry while it was being written:
    'cache-hashes.json: cannot write'."""
    from zcomp_cli.blender import cache as bcache
    from zcomp_cli.camera import Camera
    from zcomp_cli.testing import sphere_object_bundle

    cam = Camera.from_fov(50, 16, 12)
    bundle = sphere_object_bundle(cam, (0, 0, -3), 0.5)
    cache, key = tmp_path / "cache", "cd" * 32
    errors: list[BaseException] = []
    inodes: set[int] = set()

    def writer(k: int) -> None:
        for i in range(12):
            src = tmp_path / f"w{k}-{i}"
            bundle.save(src)
            try:
                entry = bcache.store(cache, key, src)
                inodes.add(entry.stat().st_ino)
                assert bcache.lookup(cache, key) == entry
            except BaseException as exc:  # noqa: BLE001 - collected for the assert
                errors.append(exc)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors[:3]
    assert len(inodes) == 1, "an intact entry was replaced"
    assert bcache.lookup(cache, key) is not None
    assert not [p for p in cache.iterdir() if p.name.startswith(".work-")]  # no scratch left


# ------------------------------------------------------------------ 6. special files
def _special(project: Path, kind: str) -> tuple[dict, str]:
    doc = base_manifest()
    if kind == "fifo-image":
        os.mkfifo(project / "scenes/fifo.png")
        doc["scenes"]["room"]["image"] = "scenes/fifo.png"
        return doc, "scenes.room.image"
    if kind == "fifo-map":
        os.mkfifo(project / "scenes/fifo.exr")
        doc["scenes"]["room"]["depth"] = "scenes/fifo.exr"
        return doc, "scenes.room.depth"
    if kind == "dev-zero-mesh":
        (project / "objects/zero.obj").symlink_to("/dev/zero")
        doc["objects"]["zero"] = {"mesh": "objects/zero.obj"}
        doc["jobs"].append({"scene": "room", "object": "zero", "pose": {"position": [0, -1, -3]}})
        return doc, "objects.zero.mesh"
    if kind == "fifo-in-bundle":
        (project / "objects/ball/albedo.exr").unlink()
        os.mkfifo(project / "objects/ball/albedo.exr")
        return doc, "objects.ball.bundle"
    if kind == "char-device-reference":
        (project / "ref.png").symlink_to("/dev/null")
        doc["jobs"][0]["reference"] = "ref.png"
        return doc, "jobs[0].reference"
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["fifo-image", "fifo-map", "dev-zero-mesh", "fifo-in-bundle",
                                  "char-device-reference"])
def test_special_files_are_refused_at_validation(project, kind):
    doc, field = _special(project, kind)
    m = _write(project, doc)
    try:
        r = subprocess.run(_zcomp("-q", "composite", m, "--out", project / "out"), env=_env(),
                           capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"zcomp hangs on {kind}")
    assert r.returncode == 2 and field in r.stderr and "not a regular file" in r.stderr, r.stderr
    assert not (project / "out").exists()


# ------------------------------------------------------------------ 7. damaged reports, bounded counts
@pytest.mark.parametrize("content", ["[]", '"done"', "3"])
def test_damaged_report_is_treated_as_missing(project, content):
    out = project / "out"
    assert _composite(project / "jobs.yaml", out).exit_code == 0
    (out / "000_room_ball/report.json").write_text(content)
    r = _composite(project / "jobs.yaml", out, "--resume")
    assert r.exit_code == 0, r.output
    assert _this_run(out) == {"000_room_ball": "done", "001_room_card": "skipped"}
    st = CliRunner().invoke(cli, ["status", str(out)])
    assert st.exit_code == 0 and "Traceback" not in st.output


SUMMARY_SHAPES = ["[]", "3", '"x"', '{"jobs": 3}', '{"jobs": [1, 2]}', '{"jobs": [{"name": [1]}]}',
                  '{"shard": [1]}', '{"shard": {"index": "0", "count": 2}}', '{"shard": {"index": 0, "count": 2, '
                  '"jobs": 5}}']
REPORT_SHAPES = ['{"status": "done", "outputs": 3}', '{"status": "done", "outputs": {"composite.png": 3}}',
                 '{"status": "done", "outputs": {"../../x": {"bytes": 1}}}', '[]']


@pytest.mark.parametrize("where, content", [("summary.shard-0-of-2.json", x) for x in SUMMARY_SHAPES]
                         + [("000_room_ball/report.json", x) for x in REPORT_SHAPES])
def test_status_survives_wrongly_typed_summaries_and_reports(project, where, content):
    out = project / "out"
    assert _composite(project / "jobs.yaml", out).exit_code == 0
    (out / where).write_text(content)
    code, d = _status(out)
    if where.startswith("summary"):  # skipped with a note; the reports still tell
        assert code == 0 and d["done"] == 2 and d["notes"], d
    else:  # that job is not done
        assert code == 1 and d["done"] == 1, d


def test_a_huge_shard_count_is_bounded(project):
    out = project / "out"
    assert _composite(project / "jobs.yaml", out).exit_code == 0
    (out / "summary.shard-0-of-300000000.json").write_text(json.dumps(
        {"shard": {"index": 0, "count": 300_000_000, "jobs": []}, "jobs": []}))
    t = time.monotonic()
    st = CliRunner().invoke(cli, ["status", str(out), "--json"])
    assert time.monotonic() - t < 10
    d = json.loads(st.output)
    assert d["done"] == 2 and any("300000000" in n for n in d["notes"]) and len(d["shards"]) == 0


# ------------------------------------------------------------------ 8. status judges as --resume does
@pytest.mark.parametrize("damage", ["delete-png", "empty-exr", "edit-png"])
def test_status_checks_the_outputs(project, damage):
    out = project / "out"
    assert _composite(project / "jobs.yaml", out).exit_code == 0
    job = out / "000_room_ball"
    if damage == "delete-png":
        (job / "composite.png").unlink()
    elif damage == "empty-exr":
        (job / "composite.exr").write_bytes(b"")
    else:
        data = bytearray((job / "composite.png").read_bytes())
        data[-20] ^= 0xFF
        (job / "composite.png").write_bytes(bytes(data))
    code, d = _status(out)
    assert code == 1 and d["done"] == 1 and list(d["jobs"]["damaged"]) == ["000_room_ball"], d


def test_status_with_the_manifest_sees_changed_inputs(project):
    doc = base_manifest()
    m = _write(project, doc)
    out = project / "out"
    assert _composite(m, out).exit_code == 0
    assert _status(out, "--manifest", m)[0] == 0
    doc["jobs"][0]["shading_radius"] = 2.0
    _write(project, doc)
    code, d = _status(out, "--manifest", m)
    assert code == 1 and d["jobs"]["changed"] == ["000_room_ball"] and d["done"] == 1, d
    # the renderer a job was made with (a command-line override) is not a change
    assert _composite(m, out, "--resume", "--redo-changed", "--renderer", "physical").exit_code == 0
    assert _status(out, "--manifest", m)[0] == 0


# ------------------------------------------------------------------ 9. non-finite vertices
def test_obj_with_a_nan_vertex_is_refused_naming_the_file(project):
    (project / "objects/bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv nan 0.5 0\nv 1 1 inf\n"
                                             "f 1 2 3\nf 2 4 3\nf 1 5 2\n")
    doc = base_manifest()
    doc["objects"]["bad"] = {"mesh": "objects/bad.obj"}
    doc["jobs"].append({"scene": "room", "object": "bad", "pose": {"position": [0, -1, -3]}})
    r = _composite(_write(project, doc), project / "out")
    assert r.exit_code == 2 and "objects.bad.mesh" in r.output and "non-finite" in r.output, r.output
    assert not (project / "out").exists()


def test_binary_meshes_with_non_finite_vertices_are_refused(tmp_path):
    from zcomp_cli.blender.meshes import load_mesh_info
    from zcomp_cli.errors import GeometryError

    ply = tmp_path / "bad.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
                   "property float z\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n"
                   "0 0 0\n1 0 0\n0 1 0\nnan 1 0\n3 0 1 2\n3 1 3 2\n")
    with pytest.raises(GeometryError, match="non-finite"):
        load_mesh_info(ply)


# ------------------------------------------------------------------ 10. textures in the pixel budget
def _mtl_textured(project: Path) -> str:
    textured_quad(project / "objects/quad")
    write_png(project / "objects/quad/tex.png", np.zeros((40, 40, 3), np.float32))
    return "objects/quad/quad.obj"


def _glb_textured(project: Path) -> str:
    import trimesh
    from PIL import Image

    quad = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False)
    quad.visual = trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]],
                                                image=Image.new("RGB", (40, 40), (200, 10, 10)))
    (project / "objects/quad.glb").write_bytes(quad.export(file_type="glb"))
    return "objects/quad.glb"


@pytest.mark.parametrize("make, needle", [(_mtl_textured, "tex.png"), (_glb_textured, "images[0]")])
def test_a_texture_over_the_pixel_budget_is_refused(project, monkeypatch, make, needle):
    """Through an MTL, or embedded in a GLB: read from the header, against the budget."""
    doc = base_manifest()
    doc["objects"]["quad"] = {"mesh": make(project)}
    doc["jobs"].append({"scene": "room", "object": "quad", "pose": {"position": [0, -1, -3]}})
    monkeypatch.setenv("ZCOMP_MAX_PIXELS", "1000")  # the 32x24 scene fits; a 40x40 texture does not
    r = _composite(_write(project, doc), project / "out")
    assert r.exit_code == 2 and "objects.quad.mesh" in r.output and "40x40" in r.output, r.output
    assert "pixel budget" in r.output and needle in r.output


# ------------------------------------------------------------------ 11. YAML 1.2 floats
def test_every_yaml_12_float_form_is_a_number(project):
    from zcomp_cli.yamlloc import load_yaml

    p = project / "f.yaml"
    p.write_text("a: 1.0e6\nb: 1.5E3\nc: .5e1\nd: 12\ne: 1e9\nf: '1.0e6'\n")
    assert load_yaml(p) == {"a": 1e6, "b": 1500.0, "c": 5.0, "d": 12, "e": 1e9, "f": "1.0e6"}
    doc = base_manifest()
    text = yaml.safe_dump(doc, sort_keys=False).replace("height: 0.4", "height: 0.04e1")
    assert "0.04e1" in text
    (project / "m.yaml").write_text(text)
    assert _composite(project / "m.yaml", project / "out").exit_code == 0


# ------------------------------------------------------------------ 12. names
@pytest.mark.parametrize("name", ["newline\n", "summary.shard-0-of-2.json", "0", "3-5"])
def test_output_names_that_break_a_run_are_refused(project, name):
    doc = base_manifest()
    doc["jobs"][0]["output"] = name
    r = _composite(_write(project, doc), project / "out")
    assert r.exit_code == 2 and "jobs[0].output" in r.output, r.output
    assert not (project / "out").exists()


# ------------------------------------------------------------------ 13. validated before anything is written
@pytest.mark.parametrize("edit, needle", [
    (lambda d: d["defaults"].update(renderer="nope"), "unknown renderer"),
    (lambda d: d["defaults"].update(renderer={"name": "physical", "colour": 3}), "colour"),
    (lambda d: d["defaults"].update(renderer={"name": "physical", "march_steps": 0}), "march_steps"),
    (lambda d: d["jobs"][1].update(pose={"position": [0, -1, -3]}, placement=None) or d["jobs"][1].pop("placement"),
     "needs a 'placement'"),
    (lambda d: d["jobs"][1]["placement"].pop("height"), "placement.height"),
])
def test_manifest_mistakes_are_refused_with_their_line_before_anything_is_written(project, edit, needle):
    doc = base_manifest()
    edit(doc)
    r = _composite(_write(project, doc), project / "out")
    assert r.exit_code == 2 and needle in r.output, r.output
    assert "m.yaml:" in r.output  # the line
    assert not (project / "out").exists()


def test_2d_object_mask_mistakes_are_refused_at_validation(project):
    write_png(project / "objects/small_mask.png", np.ones((8, 8), np.float32), srgb_encode=False)
    write_png(project / "objects/empty_mask.png", np.zeros((16, 16), np.float32), srgb_encode=False)
    for mask, needle in (("objects/small_mask.png", "8x8"), ("objects/empty_mask.png", "selects no pixel")):
        doc = base_manifest()
        doc["objects"]["card"]["mask"] = mask
        r = _composite(_write(project, doc), project / "out")
        assert r.exit_code == 2 and "objects.card.mask" in r.output and needle in r.output, r.output
        assert not (project / "out").exists()


def test_run_setup_mistakes_write_nothing(project, monkeypatch, no_ray):
    out = project / "out"
    monkeypatch.delenv("ZCOMP_CONTROLNET", raising=False)
    monkeypatch.delenv("ZCOMP_SD_BASE", raising=False)
    r = _composite(project / "jobs.yaml", out, "--renderer", "zerocomp")  # no weights anywhere
    assert r.exit_code == 2 and "weights not found" in r.output, r.output
    assert not out.exists()
    r = _composite(project / "jobs.yaml", out, "--renderer", "physical", "--march-steps", "0")
    assert r.exit_code == 2 and not out.exists(), r.output
    no_ray()
    r = _composite(project / "jobs.yaml", out, "--executor", "ray")
    assert r.exit_code == 2 and "zcomp[ray]" in r.output and not out.exists(), r.output


# ------------------------------------------------------------------ 14. redo exactly the changed jobs
def test_redo_changed_redoes_exactly_the_changed_job(project):
    doc = base_manifest()
    m = _write(project, doc)
    out = project / "out"
    assert _composite(m, out).exit_code == 0
    card = (out / "001_room_card/composite.png").stat().st_mtime_ns
    doc["jobs"][0]["seed"] = 1234
    _write(project, doc)
    assert _composite(m, out, "--resume").exit_code == 2
    assert _composite(m, out, "--redo-changed").exit_code == 2  # it goes with --resume
    assert _composite(m, out, "--resume", "--redo-changed").exit_code == 0
    assert _this_run(out) == {"000_room_ball": "done", "001_room_card": "skipped"}
    assert (out / "001_room_card/composite.png").stat().st_mtime_ns == card


def test_resume_with_debug_writes_the_debug_maps(project):
    out = project / "out"
    assert _composite(project / "jobs.yaml", out).exit_code == 0
    assert _composite(project / "jobs.yaml", out, "--debug").exit_code == 2  # nothing replaced unasked
    assert _composite(project / "jobs.yaml", out, "--resume", "--debug").exit_code == 0
    for job in ("000_room_ball", "001_room_card"):
        assert (out / job / "debug/f_bg.exr").is_file() and (out / job / "grid.png").is_file()
    assert _composite(project / "jobs.yaml", out, "--resume", "--debug").exit_code == 0
    assert set(_this_run(out).values()) == {"skipped"}


# ------------------------------------------------------------------ 15. eval
def test_eval_lists_a_job_of_another_size_as_unscored(project):
    doc = base_manifest()
    write_png(project / "ref.png", np.full((24, 32, 3), 0.3, np.float32))
    write_png(project / "small_ref.png", np.full((12, 16, 3), 0.3, np.float32))
    doc["jobs"][0]["reference"] = "ref.png"
    doc["jobs"][1]["reference"] = "small_ref.png"
    out = project / "out"
    assert _composite(_write(project, doc), out).exit_code == 0
    r = CliRunner().invoke(cli, ["eval", str(out), "--metrics", "psnr"])
    assert r.exit_code == 0, r.output
    d = json.loads((out / "eval.json").read_text())
    assert [i["name"] for i in d["images"]] == ["000_room_ball"]
    assert "size mismatch" in d["unscored"]["001_room_card"] and "001_room_card" in r.output


def test_a_folder_as_reference_is_refused_at_validation(project):
    doc = base_manifest()
    doc["jobs"][0]["reference"] = "scenes"
    r = _composite(_write(project, doc), project / "out")
    assert r.exit_code == 2 and "jobs[0].reference" in r.output and "folder" in r.output, r.output


# ------------------------------------------------------------------ 16. folders that are not job folders
def test_outputs_into_input_folders_are_refused(project):
    doc = base_manifest()
    doc["jobs"][0]["output"] = "scenes"  # --out is the manifest's folder
    doc["jobs"][1]["output"] = "README.md"
    (project / "README.md").write_text("notes\n")
    before = {p: p.read_bytes() for p in (project / "scenes").iterdir()}
    r = _composite(_write(project, doc), project)
    assert r.exit_code == 2 and "not a zcomp job folder" in r.output and "not a folder" in r.output, r.output
    assert {p: p.read_bytes() for p in (project / "scenes").iterdir()} == before
    assert not (project / "summary.json").exists()


# ------------------------------------------------------------------ 17. minimum sides, option names
def test_a_mesh_scene_smaller_than_blender_renders_is_refused(tmp_path):
    make_project(tmp_path, width=10, height=2)
    (tmp_path / "objects/tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    doc = base_manifest(10, 2)
    doc["objects"]["tri"] = {"mesh": "objects/tri.obj"}
    doc["jobs"] = [{"scene": "room", "object": "tri", "pose": {"position": [0, -1, -3]}}]
    r = _composite(_write(tmp_path, doc), tmp_path / "out")
    assert r.exit_code == 2 and "scenes.room.image" in r.output and "4x4" in r.output, r.output


@pytest.mark.parametrize("flags, option", [(["--resolution", "1", "1"], "--resolution"),
                                           (["--fov-deg", "nan"], "--fov-deg"), (["--fov-deg", "190"], "--fov-deg")])
def test_render_intrinsics_names_the_bad_option(tmp_path, flags, option):
    mesh = tmp_path / "m.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r = CliRunner().invoke(cli, ["render-intrinsics", "--mesh", str(mesh), "--position", "0", "0", "-3", *flags,
                                 "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and option in r.output, r.output
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------ 18. a probe without light
@pytest.mark.parametrize("value", [0.0, -1.0, np.nan])
def test_a_probe_without_light_is_refused(project, value):
    write_exr(project / "probe.exr", np.full((8, 16, 3), value, np.float32))
    doc = base_manifest()
    doc["scenes"]["room"]["light"] = {"type": "probe", "hdr": "probe.exr"}
    r = _composite(_write(project, doc), project / "out")
    assert r.exit_code == 2 and "scenes.room.light.hdr" in r.output and "no light" in r.output, r.output


# ------------------------------------------------------------------ 19. shards beyond the job count
def test_more_shards_than_jobs_is_cheap(project):
    doc = base_manifest()
    doc["jobs"] = [{"scene": "room", "object": "card", "output": f"j{i:04d}",
                    "placement": {"pixel": [8 + i % 16, 18], "height": 0.3}} for i in range(2000)]
    m = _write(project, doc)
    try:
        r = subprocess.run(_zcomp("-q", "composite", m, "--out", project / "out", "--shard", "5/100000"),
                           env=_env(), capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("--shard 5/100000 hangs")
    assert r.returncode == 0, r.stderr
    assert json.loads((project / "out/summary.shard-5-of-100000.json").read_text())["shard"]["jobs"] == ["j0005"]
    r = _composite(m, project / "out", "--shard", "0/10000000")
    assert r.exit_code == 2 and "at most" in r.output


# ------------------------------------------------------------------ 20. formats, one overwrite rule
def test_a_jpeg_named_png_is_read_as_what_it_is(project):
    from PIL import Image

    from zcomp_cli.imageio import verify_image

    img = Image.open(project / "scenes/room.png").convert("RGB")
    img.save(project / "scenes/room.png", format="JPEG", quality=95)  # a JPEG, named .png
    assert verify_image(project / "scenes/room.png")[:2] == (32, 24)
    assert _composite(project / "jobs.yaml", project / "out").exit_code == 0
    data = (project / "scenes/room.png").read_bytes()
    (project / "scenes/room.png").write_bytes(data[: len(data) - 40])
    r = _composite(project / "jobs.yaml", project / "out2")
    assert r.exit_code == 2 and "a JPEG file named .png" in r.output and "truncated PNG" not in r.output, r.output


def test_estimate_does_not_overwrite_without_overwrite(project):
    out = project / "est"
    args = ["-q", "estimate", str(project / "jobs.yaml"), "--out", str(out)]
    assert CliRunner().invoke(cli, args).exit_code == 0
    first = (out / "room/sources.json").stat().st_mtime_ns
    r = CliRunner().invoke(cli, args)
    assert r.exit_code == 2 and "--overwrite" in r.output, r.output
    assert (out / "room/sources.json").stat().st_mtime_ns == first
    assert CliRunner().invoke(cli, [*args, "--overwrite"]).exit_code == 0
