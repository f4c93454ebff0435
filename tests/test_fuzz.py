"""Fuzzing ``zcomp composite`` with Hypothesis (issue 12).

Each case is a manifest derived from a valid one by random hostile edits (wrong types,
out-of-range numbers, NaN/Inf, huge sizes, path tricks, aliases, truncated YAML) and
optionally scene maps or an object bundle full of NaN/Inf/zeros/extremes. The case
runs through the real CLI (in process, naive or physical renderer, 32x24 pixels, no
Blender) and must keep every invariant:

* the exit code is 0, 1 or 2, and no Python traceback is shown (no ``-v``);
* nothing is written outside ``--out`` (apart from zcomp's cache);
* every JSON file written parses with a strict parser (no NaN / Infinity);
* every composite is finite; for a finished job, the pixels outside the region the
  renderer touched (its report's ``roi``) are bit-identical to the background.

Profiles (``ZCOMP_FUZZ_PROFILE``): ``ci`` (default) runs 200 cases, ``full`` 1000:

    ZCOMP_FUZZ_PROFILE=full pytest -m fuzz tests/test_fuzz.py -q

The crash test (``kill -9`` at random moments of a 12-job batch, then ``--resume``
until done) is marked ``slow``.
"""

from __future__ import annotations

import json
import os
import random
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

from hostile_project import base_manifest, make_project
from zcomp_cli.cli import cli

settings.register_profile("ci", max_examples=200, deadline=None, derandomize=True, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                 HealthCheck.function_scoped_fixture])
settings.register_profile("full", parent=settings.get_profile("ci"), max_examples=1000, derandomize=False)
PROFILE = os.environ.get("ZCOMP_FUZZ_PROFILE", "ci")

SRC = Path(__file__).resolve().parents[1] / "src"
STATS = {"cases": 0, "exit": {0: 0, 1: 0, 2: 0}, "done_jobs": 0}

# ----------------------------------------------------------------------------- values
_weird_text = st.sampled_from([
    "", ".", "..", "../..", "/", "/etc/passwd", "a/b", "..\\x", "~", "$HOME", "summary.json", "x" * 300,
    "nul\0byte", "ümlaut", "scenes/room.png", "objects/ball", "scenes", "-1", "1e9", "nan", "inf", "yes",
    "room", "ball", "card", " room", "CON", "*", "&a", "{}", "[]",
])
_numbers = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0, -1, 1, 2**31, 2**32, 2**63, 1e-300, -0.0, 1e300, 0.5, 469]),
)
_scalars = st.one_of(_numbers, _weird_text, st.text(max_size=20), st.booleans(), st.none())
_values = st.recursive(_scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                         st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                       max_leaves=8)
_vec = lambda n: st.lists(_numbers, min_size=n, max_size=n)  # noqa: E731

# Fields of the base manifest a mutation may replace, and values that fit them well
# enough to get past the first check now and then.
FIELDS = {
    ("defaults", "renderer"): st.one_of(st.sampled_from(["naive", "physical", "zerocomp", "nope"]),
                                        st.fixed_dictionaries({"name": st.sampled_from(["physical", "naive"]),
                                                               "march_steps": _scalars})),
    ("defaults", "resolution"): st.one_of(st.sampled_from([[16, 12], [64, 48], [32, 24], [4, 3], [1, 1],
                                                           [0, 0], [40960, 30720], "native", None]),
                                          _vec(2)),
    ("defaults", "seed"): _numbers,
    ("defaults", "shading_radius"): _numbers,
    ("defaults", "samples"): _numbers,
    ("scenes", "room", "image"): _weird_text,
    ("scenes", "room", "fov_deg"): _numbers,
    ("scenes", "room", "K"): st.one_of(st.lists(_vec(3), min_size=3, max_size=3),
                                      st.just([[30, 0, 16], [0, 30, 12], [0, 0, 1]]),
                                      st.just([[30, 0, 16], [0, 45, 12], [0, 0, 1]])),
    ("scenes", "room", "depth"): st.one_of(_weird_text, st.just({"proxy": "ground_plane", "camera_height": 1.2,
                                                                 "pitch_deg": -25}), _values),
    ("scenes", "room", "normals"): st.one_of(_weird_text, _values),
    ("scenes", "room", "albedo"): st.one_of(_weird_text, _values),
    ("objects", "ball", "bundle"): _weird_text,
    ("objects", "card", "mask"): _weird_text,
    ("jobs", 0, "pose", "position"): st.one_of(_vec(3), _values),
    ("jobs", 0, "pose", "height"): _numbers,
    ("jobs", 0, "pose", "rotation_deg"): _vec(3),
    ("jobs", 0, "pose", "quaternion"): _vec(4),
    ("jobs", 0, "output"): st.one_of(_weird_text, st.text(max_size=12)),
    ("jobs", 0, "seed"): _numbers,
    ("jobs", 0, "shading_radius"): _numbers,
    ("jobs", 0, "scene"): st.one_of(_weird_text, _values),
    ("jobs", 1, "placement", "pixel"): st.one_of(_vec(2), st.sampled_from([[16, 20], [31.99, 23.99], [0, 0],
                                                                          [32, 24], [-1, 5]])),
    ("jobs", 1, "placement", "height"): _numbers,
    ("jobs", 1, "placement", "yaw_deg"): _numbers,
    ("jobs", 1, "placement", "scale"): _numbers,
    ("jobs", 1, "object"): st.one_of(_weird_text, _values),
    ("jobs", 1, "reference"): _weird_text,
}
FIELD_KEYS = list(FIELDS)

MAP_DAMAGE = ["nan", "inf", "zero", "negative", "huge", "tiny", "wrong_size", "one_channel", "speckle"]


@st.composite
def cases(draw):
    """(manifest text, map damage {map: kind}, bundle damage {map: kind}, renderer name)."""
    doc = base_manifest()
    renderer = draw(st.sampled_from(["naive", "naive", "physical"]))
    # The physical renderer, made cheap (its default shadow marching dominates the run).
    doc["defaults"]["renderer"] = renderer if renderer == "naive" else {
        "name": "physical", "march_steps": 4, "estimate_march_steps": 4, "n_light_candidates": 16,
        "cone_samples": 2, "max_fit_pixels": 500}
    # Few edits, so that about half the cases get past validation and exercise the run.
    n_edits = draw(st.sampled_from([0, 0, 0, 1, 1, 2, 3, 4]))
    for _ in range(n_edits):
        path = draw(st.sampled_from(FIELD_KEYS))
        op = draw(st.sampled_from(["set", "set", "set", "delete", "unknown_key"]))
        node = doc
        for k in path[:-1]:
            node = node[k] if isinstance(node, dict) or (isinstance(node, list) and k < len(node)) else None
            if not isinstance(node, (dict, list)):
                break
        if not isinstance(node, dict):
            continue
        if op == "set":
            node[path[-1]] = draw(FIELDS[path])
        elif op == "delete":
            node.pop(path[-1], None)
        else:
            node[draw(st.sampled_from(["colour", "Scene", "pose ", "x"]))] = draw(_scalars)
    if draw(st.integers(0, 9)) == 9:  # more jobs, sharing one (aliased) pose object
        shared = {"position": [0.0, -1.2, -3.0]}
        doc["jobs"] += [{"scene": "room", "object": "ball", "pose": shared, "output": f"extra{i}"}
                        for i in range(draw(st.integers(1, 3)))]
    text = yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)
    # Hypothesis favours small integers: the rare damage sits at the top of the range.
    raw = draw(st.integers(0, 29))
    if raw == 29:  # a truncated file
        text = text[: draw(st.integers(0, len(text)))]
    elif raw == 28:  # an alias bomb in an unused key
        text += "x: &a [1,1,1,1,1,1,1,1,1,1]\n" + "".join(
            f"x{i}: &a{i} [{', '.join(['*a' if i == 0 else f'*a{i - 1}'] * 10)}]\n" for i in range(7))
    elif raw == 27:  # garbage bytes
        text = text[: len(text) // 2] + draw(st.text(max_size=30)) + text[len(text) // 2:]
    maps = {}
    if draw(st.integers(0, 1)) == 1:
        for m in draw(st.lists(st.sampled_from(["image", "depth", "normals", "albedo"]), max_size=3, unique=True)):
            maps[m] = draw(st.sampled_from(MAP_DAMAGE))
    bundle = {}
    if draw(st.integers(0, 3)) == 3:
        for m in draw(st.lists(st.sampled_from(["depth", "normals", "albedo", "mask", "footprint_depth"]),
                               min_size=1, max_size=2, unique=True)):
            bundle[m] = draw(st.sampled_from(MAP_DAMAGE))
    return text, maps, bundle, renderer


def _damage(arr: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    a = np.array(arr, dtype=np.float32, copy=True)
    if kind == "nan":
        a[rng.random(a.shape[:2]) < 0.3] = np.nan
    elif kind == "inf":
        a[rng.random(a.shape[:2]) < 0.3] = np.inf
        a[rng.random(a.shape[:2]) < 0.1] = -np.inf
    elif kind == "zero":
        a[:] = 0
    elif kind == "negative":
        a = -np.abs(a) - 1
    elif kind == "huge":
        a = a * 1e30 + 1e30
    elif kind == "tiny":
        a = a * 1e-30
    elif kind == "wrong_size":
        a = a[: a.shape[0] // 2]
    elif kind == "one_channel":
        a = a[..., :1] if a.ndim == 3 else a
    elif kind == "speckle":
        a = a + rng.normal(0, 10, a.shape).astype(np.float32)
    return a


# ----------------------------------------------------------------------------- checks
def _snapshot(root: Path, skip: Path) -> dict[str, tuple]:
    out = {}
    for p in root.rglob("*"):
        if skip in p.parents or p == skip:
            continue
        try:
            st_ = p.lstat()
        except OSError:
            continue
        out[str(p)] = (st_.st_size, st_.st_mtime_ns) if p.is_file() else ("dir",)
    return out


def _tmp_zcomp_entries() -> set[str]:
    """zcomp's temporaries of THIS process (their names carry the pid; other processes
    on the machine may be running zcomp too)."""
    pid = str(os.getpid())
    return {p for p in os.listdir(tempfile.gettempdir())
            if p.startswith("zcomp-") and pid in p.split("-")}


def _strict_json(path: Path):
    def bad(c):
        raise AssertionError(f"{path}: non-strict JSON constant {c}")
    return json.loads(path.read_text(), parse_constant=bad)


def _check_far_background(case_dir: Path, manifest: Path, job_dir: Path, report: dict) -> None:
    from zcomp_cli.imageio import read_image
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.pipeline.scene import load_scene

    m = load_manifest(manifest)
    spec = m.scenes[report["job"]["scene"]]
    bg = load_scene(spec, m.defaults.resolution).background  # (negative pixels as read)
    img = read_image(job_dir / "composite.exr")
    assert img.shape == bg.shape, (img.shape, bg.shape)
    x0, y0, x1, y1 = report["roi"]["box"]
    far = np.ones(bg.shape[:2], bool)
    far[y0:y1, x0:x1] = False
    assert np.array_equal(img[far], bg[far]), f"{job_dir.name}: background changed outside the roi"


def _run_case(root: Path, shared: Path, case, n: int) -> None:
    text, maps, bundle, renderer = case
    from zcomp_cli.bundle import ObjectBundle
    from zcomp_cli.imageio import read_image, read_map, write_exr

    case_dir = root / f"case{n}"
    if case_dir.exists():
        shutil.rmtree(case_dir)
    shutil.copytree(shared, case_dir, symlinks=True)
    rng = np.random.default_rng(n)
    for m, kind in maps.items():
        if m == "image":
            img = _damage(read_image(shared / "scenes/room.png"), kind, rng)
            write_exr(case_dir / "scenes/room.exr", img)
            text = text.replace("scenes/room.png", "scenes/room.exr")
        else:
            write_exr(case_dir / f"scenes/{m}.exr", _damage(read_map(shared / f"scenes/{m}.exr"), kind, rng))
    if bundle:
        b = ObjectBundle.load(shared / "objects/ball")
        for m, kind in bundle.items():
            setattr(b, m, _damage(getattr(b, m), kind, rng))
        try:
            b.save(case_dir / "objects/ball")
        except Exception:  # noqa: BLE001 - a bundle zcomp itself refuses to write is not a case
            pass
    manifest = case_dir / "jobs.yaml"
    manifest.write_text(text)
    out = case_dir / "out"
    before = _snapshot(root, out)
    tmp_before = _tmp_zcomp_entries()

    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(out)])

    STATS["cases"] += 1
    assert r.exception is None or isinstance(r.exception, SystemExit), (
        f"uncaught {type(r.exception).__name__}: {r.exception}\n{text}")
    assert r.exit_code in (0, 1, 2), (r.exit_code, r.output, text)
    STATS["exit"][r.exit_code] += 1
    assert "Traceback" not in r.output, r.output
    # nothing written outside --out
    after = _snapshot(root, out)
    changed = {p for p in set(before) | set(after) if before.get(p) != after.get(p)}
    assert not changed, f"written outside --out: {sorted(changed)[:5]}"
    assert _tmp_zcomp_entries() <= tmp_before, "temporary files left in /tmp"
    if out.exists():
        assert out.resolve() == (case_dir / "out").resolve()
        for p in out.rglob("*"):
            assert not p.is_symlink(), p
            assert p.name != ".." and out.resolve() in p.resolve().parents, p
            if p.suffix == ".json":
                _strict_json(p)
            if p.name.startswith(".zcomp-") or ".tmp" in p.name:
                raise AssertionError(f"litter left: {p}")
        for rep_path in out.glob("*/report.json"):
            rep = _strict_json(rep_path)
            if rep.get("status") != "done":
                continue
            STATS["done_jobs"] += 1
            img = read_image(rep_path.parent / "composite.exr")
            assert np.isfinite(img).all(), rep_path
            _check_far_background(case_dir, manifest, rep_path.parent, rep)
    shutil.rmtree(case_dir, ignore_errors=True)


@pytest.fixture(scope="module")
def fuzz_root():
    root = Path(tempfile.mkdtemp(prefix="zcomp-fuzz-"))
    shared = root.parent / (root.name + "-shared")
    make_project(shared)
    yield root, shared
    shutil.rmtree(root, ignore_errors=True)
    shutil.rmtree(shared, ignore_errors=True)


@pytest.mark.fuzz
@pytest.mark.slow
@settings(settings.get_profile(PROFILE))
@given(case=cases())
def test_fuzz_composite(fuzz_root, case):
    root, shared = fuzz_root
    _run_case(root, shared, case, STATS["cases"])


@pytest.mark.fuzz
@pytest.mark.slow
def test_fuzz_report(capsys):
    """Prints the counts of the fuzz run above (for the closing note)."""
    with capsys.disabled():
        print(f"\nfuzz profile {PROFILE}: {STATS['cases']} cases, exit codes {STATS['exit']}, "
              f"{STATS['done_jobs']} finished jobs checked")


# ----------------------------------------------------------------------------- crash test
@pytest.mark.slow
def test_kill_9_at_random_moments_then_resume(tmp_path):
    """kill -9 a 12-job batch at random moments, then --resume until it finishes:
    nothing lost (finished outputs never change), nothing redone (a finished job is
    never rewritten), nothing left behind (no temporary or lock files)."""
    make_project(tmp_path, width=64, height=48)
    doc = base_manifest(64, 48)
    doc["defaults"]["renderer"] = "physical"
    doc["jobs"] = [{"scene": "room", "object": "ball" if i % 2 else "card",
                    **({"pose": {"position": [0, -1.2, -3]}} if i % 2 else
                       {"placement": {"pixel": [10 + 4 * i, 36], "height": 0.3 + 0.02 * i}}),
                    "seed": i, "output": f"job{i:02d}"} for i in range(12)]
    manifest = tmp_path / "twelve.yaml"
    manifest.write_text(yaml.safe_dump(doc, sort_keys=False))
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(SRC))
    cmd = [sys.executable, "-m", "zcomp_cli", "-q", "composite", str(manifest), "--out", str(out), "--resume"]
    rng = random.Random(12)
    finished: dict[str, dict] = {}  # job -> {file: (inode, mtime_ns, bytes)} when first seen finished
    kills = 0

    def record():
        for job_dir in sorted(out.glob("job*")):
            rep = job_dir / "report.json"
            if rep.is_file():
                d = json.loads(rep.read_text())
                files = {n: (job_dir / n) for n in d["outputs"]}
                state = {n: (p.stat().st_ino, p.stat().st_mtime_ns, p.read_bytes()) for n, p in files.items()}
                if job_dir.name in finished:
                    assert finished[job_dir.name] == state, f"{job_dir.name} was rewritten or lost"
                else:
                    finished[job_dir.name] = state

    def reports() -> int:
        return sum(1 for _ in out.glob("job*/report.json"))

    done_under_kills = 0
    for attempt in range(40):
        if attempt == 30:
            done_under_kills = len(finished)
        p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        if attempt < 30:
            # the kill's moment from what this run shows, not a fixed delay (a busy
            # machine starts and renders slower): once it has finished a job, a random
            # share of the time that took, so the kill lands inside a later job, in its
            # writing, or between two
            n0, t0 = reports(), time.monotonic()
            while p.poll() is None and reports() == n0 and time.monotonic() - t0 < 600:
                time.sleep(0.01)
            time.sleep(rng.uniform(0.0, 1.0) * (time.monotonic() - t0))
        try:
            rc = p.wait(timeout=0.01 if attempt < 30 else 300)
        except subprocess.TimeoutExpired:
            os.kill(p.pid, signal.SIGKILL)
            p.wait()
            kills += 1
            rc = None
        p.stdout.close()
        p.stderr.close()
        record()
        if rc == 0:
            break
    assert rc == 0, "the batch never finished"
    done_under_kills = done_under_kills if attempt >= 30 else len(finished)
    print(f"\ncrash test: {kills} kill -9, {attempt + 1} runs until done, "
          f"{done_under_kills} of 12 jobs finished by runs that were then killed")
    assert done_under_kills >= 3, "the kills never landed between jobs"
    assert kills >= 3, f"only {kills} kills landed: the batch is too fast for this test"
    assert sorted(finished) == [f"job{i:02d}" for i in range(12)]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["done"] == 12 and summary["pending"] == 0
    leftovers = [p for p in out.rglob("*") if ".tmp" in p.name or p.name.startswith(".zcomp-")]
    assert not leftovers, leftovers
    dead = [e for e in os.listdir(tempfile.gettempdir()) if e.startswith("zcomp-job-")]
    from zcomp_cli.pipeline.outguard import _pid_of, pid_alive
    assert not [e for e in dead if (pid := _pid_of(e, "zcomp-job-")) and not pid_alive(pid)]
    # a final resume does nothing
    r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and "0 done, 12 skipped" in r.stderr + r.stdout
    record()
