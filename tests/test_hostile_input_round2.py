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
import shutil
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

from hostile_project import base_manifest, make_project
from zcomp_cli.cli import cli
from zcomp_cli.imageio import write_exr, write_png

SRC = Path(__file__).resolve().parents[1] / "src"
CHEAP_PHYSICAL = {"name": "physical", "march_steps": 4, "estimate_march_steps": 4, "n_light_candidates": 16,
                  "cone_samples": 2, "max_fit_pixels": 500}


@pytest.fixture
def project(tmp_path):
    make_project(tmp_path)
    return tmp_path


def _write(project: Path, doc, name="m.yaml") -> Path:
    p = project / name
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


def _composite(manifest, out, *extra):
    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(out), *extra])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    assert "Traceback" not in r.output, r.output
    return r


def _this_run(out: Path) -> dict[str, str | None]:
    """What the last run did to each job: done, skipped, failed (None: not selected)."""
    return {j["name"]: j["this_run"] for j in json.loads((out / "summary.json").read_text())["jobs"]}


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

    base = fp()
    room = m.scenes["room"]
    probe = dict(room.light)
    room.light = {"type": "lights", "lights": [probe, {"type": "lamp", "position": [0, 1, -2], "power": 5}]}
    mixed = fp()
    assert mixed != base
    room.light["lights"][1]["power"] = 6
    assert fp() != mixed
    room.light["convention"] = "blender"
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


def _textured_obj(folder: Path) -> Path:
    """A textured quad: OBJ -> MTL -> PNG."""
    folder.mkdir(parents=True, exist_ok=True)
    write_png(folder / "tex.png", np.random.default_rng(0).random((8, 8, 3)).astype(np.float32))
    (folder / "quad.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")
    (folder / "quad.obj").write_text(
        "mtllib quad.mtl\nv -0.5 0 0\nv 0.5 0 0\nv 0.5 1 0\nv -0.5 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    return folder / "quad.obj"


def test_fingerprint_covers_mesh_side_files(project):
    from zcomp_cli.pipeline.fingerprint import job_fingerprint
    from zcomp_cli.pipeline.manifest import load_manifest

    _textured_obj(project / "objects/quad")
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
    _textured_obj(project / "objects/quad")
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
                         stderr=subprocess.PIPE, text=True)
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
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
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


@pytest.mark.parametrize("summary", SUMMARY_SHAPES)
def test_status_survives_wrongly_typed_summaries(project, summary):
    out = project / "out"
    assert _composite(project / "jobs.yaml", out).exit_code == 0
    (out / "summary.shard-0-of-2.json").write_text(summary)
    st = CliRunner().invoke(cli, ["status", str(out), "--json"])
    assert st.exception is None or isinstance(st.exception, SystemExit), st.exc_info
    assert st.exit_code in (0, 1)
    d = json.loads(st.output)
    assert d["done"] == 2 and d["notes"], d


@pytest.mark.parametrize("report", REPORT_SHAPES)
def test_status_survives_wrongly_typed_reports(project, report):
    out = project / "out"
    assert _composite(project / "jobs.yaml", out).exit_code == 0
    (out / "000_room_ball/report.json").write_text(report)
    st = CliRunner().invoke(cli, ["status", str(out), "--json"])
    assert st.exception is None or isinstance(st.exception, SystemExit), st.exc_info
    d = json.loads(st.output)
    assert st.exit_code == 1 and d["done"] == 1


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
