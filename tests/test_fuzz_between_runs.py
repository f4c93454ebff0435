"""Fuzzing what happens *between* two runs (issue 30), with Hypothesis.

Two properties, through the real CLI:

* **Input changes.** A batch runs; Hypothesis changes one input -- a pixel of a scene
  map, a side file of an object (a bundle's map; a mesh's texture or MTL when Blender
  is installed), a manifest field, a scene's light -- and ``--resume --redo-changed``
  runs again. It must redo exactly the jobs whose inputs the change touched, skip the
  others (their files untouched), and leave every output equal to a fresh run on the
  changed inputs: every job whose fresh output differs was redone, none is stale.
* **Signals.** A batch is sent TERM, HUP, INT or KILL at a random moment; then
  ``--resume`` runs to the end. Nothing is lost (a job finished before the signal is
  not rewritten), every output equals an uninterrupted run's, and no lock, temporary
  or process (Blender included, when installed) is left behind; after TERM, HUP and
  INT the exit code is 128 + the signal and the summary says what is on disk.

Profiles (``ZCOMP_FUZZ_PROFILE``): ``ci`` (default: 20 input changes, 6 signals),
``full`` (200 and 60)::

    ZCOMP_FUZZ_PROFILE=full pytest -m fuzz tests/test_fuzz_between_runs.py -q -s
"""

from __future__ import annotations

import contextlib
import copy
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hostile_project import base_manifest, default_signals, make_project, textured_quad
from zcomp_cli.cli import cli
from zcomp_cli.imageio import read_image, read_map, write_exr, write_png

PROFILE = os.environ.get("ZCOMP_FUZZ_PROFILE", "ci")
EXAMPLES = {"ci": (20, 6), "full": (200, 60)}[PROFILE]
_base = dict(deadline=None, derandomize=PROFILE == "ci", print_blob=True,
             suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
SRC = Path(__file__).resolve().parents[1] / "src"
STATS = {"changes": 0, "redone": 0, "skipped": 0, "signals": 0, "exit": {}}
CHEAP_PHYSICAL = {"name": "physical", "march_steps": 4, "estimate_march_steps": 4, "n_light_candidates": 16,
                  "cone_samples": 2, "max_fit_pixels": 500}


def _has_bpy() -> bool:
    import importlib.util

    return importlib.util.find_spec("bpy") is not None


# ----------------------------------------------------------------------------- input changes
W, H = 48, 36


def _two_scene_project(root: Path, mesh: bool) -> None:
    """Scenes room and hall with files of their own (hall lit by a known sun), a ball
    bundle and a card; jobs: every scene x object (+ a textured quad in hall with
    Blender)."""
    make_project(root, width=W, height=H)
    for m in ("png", "depth.exr", "normals.exr", "albedo.exr"):
        src = root / "scenes" / ("room.png" if m == "png" else m)
        shutil.copy(src, root / "scenes" / (f"hall.{m}" if m == "png" else f"hall_{m}"))
    doc = base_manifest(W, H)
    doc["defaults"]["renderer"] = dict(CHEAP_PHYSICAL)
    doc["defaults"]["samples"] = 2
    doc["scenes"]["hall"] = {"image": "scenes/hall.png", "fov_deg": 50, "depth": "scenes/hall_depth.exr",
                             "normals": "scenes/hall_normals.exr", "albedo": "scenes/hall_albedo.exr",
                             "light": {"azimuth_deg": 40, "elevation_deg": 50, "strength": 3}}
    ball, card = doc["jobs"]
    # deep copies: a shared pose would be written as a YAML alias, and one change move two jobs
    doc["jobs"] = [{**copy.deepcopy(ball), "output": "room_ball"}, {**copy.deepcopy(card), "output": "room_card"},
                   {**copy.deepcopy(ball), "scene": "hall", "output": "hall_ball"},
                   {**copy.deepcopy(card), "scene": "hall", "output": "hall_card"}]
    if mesh:
        textured_quad(root / "objects/quad")
        doc["objects"]["quad"] = {"mesh": "objects/quad/quad.obj"}
        doc["jobs"].append({"scene": "hall", "object": "quad", "output": "hall_quad",
                            "pose": {"position": [0.3, -1.2, -3.2], "height": 0.5, "rotation_deg": [0, 20, 0]}})
    (root / "jobs.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))


SCENE_FILES = {"room": {"image": "scenes/room.png", "depth": "scenes/depth.exr", "normals": "scenes/normals.exr",
                        "albedo": "scenes/albedo.exr"},
               "hall": {"image": "scenes/hall.png", "depth": "scenes/hall_depth.exr",
                        "normals": "scenes/hall_normals.exr", "albedo": "scenes/hall_albedo.exr"}}


@st.composite
def changes(draw, mesh: bool):
    """(kind, details): one change of one input."""
    kinds = ["map", "map", "bundle", "field", "field", "light"] + (["mesh_side"] if mesh else [])
    kind = draw(st.sampled_from(kinds))
    px = (draw(st.integers(0, W - 1)), draw(st.integers(0, H - 1)))
    if kind == "map":
        return kind, {"scene": draw(st.sampled_from(["room", "hall"])),
                      "map": draw(st.sampled_from(["image", "depth", "normals", "albedo"])),
                      "px": px, "delta": draw(st.sampled_from([0.02, 0.2, -0.3, 1.0]))}
    if kind == "bundle":
        return kind, {"map": draw(st.sampled_from(["albedo", "depth", "normals"])),
                      "delta": draw(st.sampled_from([0.05, 0.1, 0.3])), "rows": draw(st.integers(0, H - 1))}
    if kind == "mesh_side":
        return kind, {"file": draw(st.sampled_from(["tex.png", "quad.mtl"])), "value": draw(st.floats(0.1, 0.9))}
    if kind == "light":
        return kind, {"key": draw(st.sampled_from(["strength", "azimuth_deg", "elevation_deg"])),
                      "value": draw(st.sampled_from([1.0, 2.5, 20.0, 70.0]))}
    job = draw(st.integers(0, 3))
    return kind, {"job": job, "key": draw(st.sampled_from(["seed", "shading_radius", "move"])),
                  "value": draw(st.integers(1, 9))}


def _apply(root: Path, change) -> set[str]:
    """Make the change in ``root``; return the jobs whose inputs it touched."""
    kind, d = change
    doc = yaml.safe_load((root / "jobs.yaml").read_text())
    names = [j["output"] for j in doc["jobs"]]
    if kind == "map":
        path = root / SCENE_FILES[d["scene"]][d["map"]]
        old = path.read_bytes()
        x, y = d["px"]
        if d["map"] == "image":
            img = read_image(path)
            img[y, x] = np.clip(img[y, x] + d["delta"], 0, 1)
            write_png(path, img)
        else:
            a = read_map(path)
            a[y, x] = a[y, x] + d["delta"]
            write_exr(path, a)
        if path.read_bytes() == old:  # (an 8-bit pixel that rounds back: no change at all)
            return set()
        return {n for n, j in zip(names, doc["jobs"]) if j["scene"] == d["scene"]}
    if kind == "bundle":
        from zcomp_cli.bundle import ObjectBundle

        b = ObjectBundle.load(root / "objects/ball")
        arr = getattr(b, d["map"])
        arr[d["rows"]] = arr[d["rows"]] + d["delta"]
        write_exr(root / "objects/ball" / f"{d['map']}.exr", arr)
        return {n for n, j in zip(names, doc["jobs"]) if j["object"] == "ball"}
    if kind == "mesh_side":
        if d["file"] == "tex.png":
            write_png(root / "objects/quad/tex.png", np.full((8, 8, 3), d["value"], np.float32))
        else:
            (root / "objects/quad/quad.mtl").write_text(f"newmtl m\nKd {d['value']:.3f} 1 1\nmap_Kd tex.png\n")
        return {"hall_quad"}
    if kind == "light":
        doc["scenes"]["hall"]["light"][d["key"]] = d["value"]
        (root / "jobs.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        return {n for n, j in zip(names, doc["jobs"]) if j["scene"] == "hall"}
    job = doc["jobs"][d["job"]]
    if d["key"] == "seed":
        job["seed"] = 1000 + d["value"]
    elif d["key"] == "shading_radius":
        job["shading_radius"] = 0.6 + 0.3 * d["value"]  # never the default 1.0
    elif "pose" in job:
        job["pose"]["position"][0] += 0.02 * d["value"]
    else:
        job["placement"]["pixel"][0] += d["value"]
    (root / "jobs.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    return {job["output"]}


def _run(manifest: Path, out: Path, *extra) -> tuple[int, str]:
    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(out), *map(str, extra)])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    assert "Traceback" not in r.output, r.output
    return r.exit_code, r.output


def _files(out: Path, job: str) -> dict[str, tuple]:
    d = out / job
    return {p.name: (p.read_bytes(), p.stat().st_ino, p.stat().st_mtime_ns)
            for p in (d / "composite.exr", d / "composite.png")}


@pytest.fixture(scope="module")
def change_project():
    root = Path(tempfile.mkdtemp(prefix="zcomp-fuzz-change-"))
    mesh = _has_bpy()
    _two_scene_project(root / "shared", mesh)
    yield root, mesh
    shutil.rmtree(root, ignore_errors=True)


@pytest.mark.fuzz
@pytest.mark.slow
@settings(max_examples=EXAMPLES[0], **_base)
@given(data=st.data())
def test_fuzz_an_input_changes_between_two_runs(change_project, data):
    root, mesh = change_project
    change = data.draw(changes(mesh), label="change")
    case = root / f"case{STATS['changes']}"
    shutil.rmtree(case, ignore_errors=True)
    shutil.copytree(root / "shared", case)
    cache = root / "cache"  # shared: a mesh is rendered again only when its content changed
    m, out, ref = case / "jobs.yaml", case / "out", case / "ref"
    assert _run(m, out, "--cache-dir", cache)[0] == 0
    jobs = [j["output"] for j in yaml.safe_load(m.read_text())["jobs"]]
    before = {j: _files(out, j) for j in jobs}
    touched = _apply(case, change)
    code, output = _run(m, out, "--resume", "--redo-changed", "--cache-dir", cache)
    ref_code, ref_output = _run(m, ref, "--cache-dir", cache)  # a fresh run on the changed inputs
    assert code == ref_code and code in (0, 1), (output, ref_output)
    this_run = {j["name"]: j["this_run"] for j in json.loads((out / "summary.json").read_text())["jobs"]}
    fresh_status = {j["name"]: j["status"] for j in json.loads((ref / "summary.json").read_text())["jobs"]}
    redone = {j for j, s in this_run.items() if s in ("done", "failed")}
    assert redone == touched, (change, redone, touched)  # exactly the jobs the change touched
    assert {j for j, s in this_run.items() if s == "skipped"} == set(jobs) - touched
    for j in jobs:
        if this_run[j] == "failed" or fresh_status[j] == "failed":  # the change broke it: both runs say so
            assert this_run[j] == fresh_status[j] == "failed", (j, change)
            continue
        now, fresh = _files(out, j), _files(ref, j)
        differs = fresh["composite.exr"][0] != before[j]["composite.exr"][0]
        assert not differs or j in redone, f"{j}: its fresh output differs but it was skipped ({change})"
        for name in now:
            assert now[name][0] == fresh[name][0], f"{j}/{name} is not what a fresh run makes ({change})"
            if j not in redone:
                assert now[name] == before[j][name], f"{j}/{name} was rewritten though skipped"
    STATS["changes"] += 1
    STATS["redone"] += len(redone)
    STATS["skipped"] += len(set(jobs) - redone)
    shutil.rmtree(case, ignore_errors=True)


# ----------------------------------------------------------------------------- signals
SIGNALS = [signal.SIGTERM, signal.SIGHUP, signal.SIGINT, signal.SIGKILL]


def _signal_project(root: Path, mesh: bool) -> Path:
    make_project(root, width=64, height=48)
    doc = base_manifest(64, 48)
    doc["defaults"]["renderer"] = dict(CHEAP_PHYSICAL, march_steps=16)
    doc["defaults"]["samples"] = 2
    doc["jobs"] = [{"scene": "room", "object": "ball" if i % 2 else "card", "seed": i, "output": f"job{i:02d}",
                    **({"pose": {"position": [0, -1.2, -3]}} if i % 2 else
                       {"placement": {"pixel": [10 + 4 * i, 36], "height": 0.3 + 0.02 * i}})} for i in range(10)]
    if mesh:
        textured_quad(root / "objects/quad")
        doc["objects"]["quad"] = {"mesh": "objects/quad/quad.obj"}
        doc["jobs"] += [{"scene": "room", "object": "quad", "output": f"quad{i}",
                         "pose": {"position": [0.2 * i, -1.2, -3.2], "height": 0.5}} for i in range(2)]
    p = root / "jobs.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


def _env() -> dict:
    return dict(os.environ, PYTHONPATH=str(SRC))


def _zcomp(*args) -> list[str]:
    return [sys.executable, "-m", "zcomp_cli", "-q", "composite", *map(str, args)]


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    # zombies of an exited group count as gone
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            with contextlib.suppress(OSError, IndexError):
                fields = (d / "stat").read_text().rsplit(") ", 1)[1].split()
                if int(fields[2]) == pgid and fields[0] != "Z":
                    return True
    return False


def _litter(out: Path) -> list[Path]:
    return [p for p in out.rglob("*") if p.name.startswith(".zcomp-") or ".tmp" in p.name]


def _tmp_of(pid: int) -> list[str]:
    return [e for e in os.listdir(tempfile.gettempdir()) if e.startswith("zcomp-") and f"-{pid}-" in e]


@pytest.fixture(scope="module")
def signal_project():
    root = Path(tempfile.mkdtemp(prefix="zcomp-fuzz-signal-"))
    mesh = _has_bpy()
    manifest = _signal_project(root / "shared", mesh)
    ref = root / "ref"
    r = subprocess.run(_zcomp(manifest, "--out", ref, "--cache-dir", root / "refcache"), env=_env(),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    yield root, manifest, ref
    shutil.rmtree(root, ignore_errors=True)


@pytest.mark.fuzz
@pytest.mark.slow
@settings(max_examples=EXAMPLES[1], **_base)
@given(sig=st.sampled_from(SIGNALS), after=st.integers(0, 9), delay=st.floats(0.0, 2.0))
def test_fuzz_a_signal_then_resume(signal_project, sig, after, delay):
    """The signal comes ``delay`` seconds after ``after`` jobs have finished (0: during
    the start, the planning or Blender's object renders)."""
    root, manifest, ref = signal_project
    case = root / f"case{STATS['signals']}"
    out, cache = case / "out", case / "cache"  # a fresh cache: Blender runs in every case
    shutil.rmtree(case, ignore_errors=True)
    case.mkdir()
    p = subprocess.Popen(_zcomp(manifest, "--out", out, "--cache-dir", cache), env=_env(),
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=default_signals)
    t = time.monotonic()
    while p.poll() is None and len(list(out.glob("*/report.json"))) < after and time.monotonic() - t < 120:
        time.sleep(0.02)
    time.sleep(delay)
    finished_early = p.poll() is not None
    if not finished_early:
        p.send_signal(sig)
    _, err = p.communicate(timeout=120)
    rc = p.returncode
    STATS["exit"][rc] = STATS["exit"].get(rc, 0) + 1
    assert "Traceback" not in err, err
    if finished_early or rc == 0:
        assert rc == 0, err
    elif rc == -sig and sig != signal.SIGKILL:  # before zcomp took its signals: nothing written yet
        assert not out.exists(), (sig, after, delay)
    elif sig == signal.SIGKILL:
        assert rc == -signal.SIGKILL
    else:
        assert rc == 128 + sig, (rc, err)
    t = time.monotonic()
    while _group_alive(p.pid):  # Blender dies with zcomp: no process of the run is left
        assert time.monotonic() - t < 10, f"a process of the run outlived it ({sig!r}, {after} jobs + {delay:.2f} s)"
        time.sleep(0.05)
    reports = sorted(d.parent.name for d in out.glob("*/report.json")) if out.exists() else []
    if sig != signal.SIGKILL or finished_early:
        assert not out.exists() or not _litter(out), _litter(out)
        assert not _tmp_of(p.pid), _tmp_of(p.pid)
        if (out / "summary.json").exists():
            summary = json.loads((out / "summary.json").read_text())
            assert sorted(j["name"] for j in summary["jobs"] if j["status"] == "done") == reports
    kept = {j: (out / j / "composite.exr").stat().st_ino for j in reports}
    r = subprocess.run(_zcomp(manifest, "--out", out, "--resume", "--cache-dir", cache), env=_env(),
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    for j, ino in kept.items():  # nothing finished before the signal was redone
        assert (out / j / "composite.exr").stat().st_ino == ino, f"{j} was rewritten"
    for d in sorted(ref.iterdir()):
        if (d / "report.json").is_file():  # (a job; lights/ holds each scene's light)
            for name in ("composite.exr", "composite.png"):
                assert (out / d.name / name).read_bytes() == (d / name).read_bytes(), f"{d.name}/{name} differs"
    assert not _litter(out), _litter(out)
    assert not _tmp_of(p.pid), _tmp_of(p.pid)  # swept by the resume after a KILL
    STATS["signals"] += 1
    shutil.rmtree(case, ignore_errors=True)


@pytest.mark.fuzz
@pytest.mark.slow
def test_fuzz_between_runs_report(capsys):
    """Prints the counts of the two properties above (for the closing note)."""
    with capsys.disabled():
        print(f"\nfuzz-between-runs profile {PROFILE}: {STATS['changes']} input changes "
              f"({STATS['redone']} jobs redone, {STATS['skipped']} skipped); {STATS['signals']} signals, "
              f"exit codes {dict(sorted(STATS['exit'].items()))}")
