"""The output folder under attack (issue 12): locks, containment, verified resume,
content fingerprints, a merged summary, litter. Mesh-free project, naive renderer."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from hostile_project import base_manifest, make_project
from zcomp_cli.cli import cli

SRC = Path(__file__).resolve().parents[1] / "src"


def _run(manifest, out, *extra):
    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(out), *extra])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    return r


def _summary(out) -> dict:
    return json.loads((Path(out) / "summary.json").read_text())


@pytest.fixture
def project(tmp_path):
    make_project(tmp_path)
    return tmp_path


def _three_jobs(project: Path) -> Path:
    doc = base_manifest()
    doc["jobs"].append({"scene": "room", "object": "ball", "pose": {"position": [0, -1, -3]},
                        "seed": 7, "output": "third"})
    p = project / "three.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return p


# ------------------------------------------------------------------ --jobs
@pytest.mark.parametrize("subset, needle", [("5-2", "backwards"), (",", "names no job"), ("", "names no job")])
def test_bad_job_subsets_are_usage_errors(project, subset, needle):
    r = _run(project / "jobs.yaml", project / "out", "--jobs", subset)
    assert r.exit_code == 2 and needle in r.output


# ------------------------------------------------------------------ containment
def test_symlinked_job_folder_refused(project, tmp_path_factory):
    outside = tmp_path_factory.mktemp("outside")
    out = project / "out"
    out.mkdir()
    (out / "000_room_ball").symlink_to(outside, target_is_directory=True)
    r = _run(project / "jobs.yaml", out, "--overwrite")
    assert r.exit_code == 2 and "symbolic link" in r.output and "jobs[0].output" in r.output
    assert list(outside.iterdir()) == []


def test_symlinked_debug_folder_refused(project, tmp_path_factory):
    outside = tmp_path_factory.mktemp("outside")
    out = project / "out"
    (out / "000_room_ball").mkdir(parents=True)
    (out / "000_room_ball" / "debug").symlink_to(outside, target_is_directory=True)
    r = _run(project / "jobs.yaml", out, "--debug")
    assert r.exit_code == 2 and "symbolic link" in r.output
    assert list(outside.iterdir()) == []


def test_estimate_refuses_symlinked_scene_folder(project, tmp_path_factory):
    outside = tmp_path_factory.mktemp("outside")
    out = project / "est"
    out.mkdir()
    (out / "room").symlink_to(outside, target_is_directory=True)
    r = CliRunner().invoke(cli, ["-q", "estimate", str(project / "jobs.yaml"), "--out", str(out)])
    assert r.exit_code == 2 and "symbolic link" in r.output
    assert list(outside.iterdir()) == []


def test_unwritable_cache_is_a_usage_error(project, monkeypatch):
    monkeypatch.setenv("ZCOMP_CACHE_DIR", "/proc/zcomp-cache")
    r = _run(project / "jobs.yaml", project / "out")
    assert r.exit_code == 2 and "ZCOMP_CACHE_DIR" in r.output
    assert not (project / "out").exists()


# ------------------------------------------------------------------ verified resume
def test_resume_redoes_empty_missing_or_altered_outputs(project):
    out = project / "out"
    assert _run(project / "jobs.yaml", out).exit_code == 0
    rep = json.loads((out / "000_room_ball" / "report.json").read_text())
    assert set(rep["outputs"]) == {"composite.exr", "composite.png"}
    assert all(v["bytes"] > 0 and len(v["sha256"]) == 64 for v in rep["outputs"].values())
    good = (out / "000_room_ball" / "composite.png").read_bytes()

    (out / "000_room_ball" / "composite.png").write_bytes(b"")  # a full disk's 0-byte file
    r = _run(project / "jobs.yaml", out, "--resume")
    assert r.exit_code == 0 and "1 done, 1 skipped" in r.output
    assert (out / "000_room_ball" / "composite.png").read_bytes() == good

    (out / "001_room_card" / "composite.exr").unlink()
    r = _run(project / "jobs.yaml", out, "--resume")
    assert "1 done, 1 skipped" in r.output

    with open(out / "000_room_ball" / "composite.png", "r+b") as f:  # same size, other bytes
        f.seek(40)
        f.write(b"\0\1\2\3")
    r = _run(project / "jobs.yaml", out, "--resume")
    assert "1 done, 1 skipped" in r.output
    r = _run(project / "jobs.yaml", out, "--resume")
    assert "0 done, 2 skipped" in r.output


def test_resume_survives_touch_and_moving_the_project(project, tmp_path_factory):
    out = project / "out"
    assert _run(project / "jobs.yaml", out).exit_code == 0
    later = time.time() + 100
    for p in project.rglob("*"):
        if p.is_file() and out not in p.parents:
            os.utime(p, (later, later))
    r = _run(project / "jobs.yaml", out, "--resume")
    assert r.exit_code == 0 and "0 done, 2 skipped" in r.output
    moved = tmp_path_factory.mktemp("moved") / "proj"
    shutil.move(str(project), str(moved))
    r = _run(moved / "jobs.yaml", moved / "out", "--resume")
    assert r.exit_code == 0 and "0 done, 2 skipped" in r.output, r.output


def test_resume_with_changed_inputs_says_overwrite(project):
    out = project / "out"
    assert _run(project / "jobs.yaml", out).exit_code == 0
    doc = yaml.safe_load((project / "jobs.yaml").read_text())
    doc["jobs"][1]["placement"]["height"] = 0.5
    (project / "jobs.yaml").write_text(yaml.safe_dump(doc))
    r = _run(project / "jobs.yaml", out, "--resume")
    assert r.exit_code == 2 and "--overwrite" in r.output and "Pass --resume" not in r.output
    assert "001_room_card" in r.output


# ------------------------------------------------------------------ summary
def test_summary_is_the_merged_state_of_the_folder(project):
    m = _three_jobs(project)
    out = project / "out"
    assert _run(m, out, "--jobs", "2").exit_code == 0
    s = _summary(out)
    assert [j["status"] for j in s["jobs"]] == ["pending", "pending", "done"]
    assert s["done"] == 1 and s["pending"] == 2
    assert _run(m, out, "--jobs", "0").exit_code == 0
    s = _summary(out)
    assert [j["status"] for j in s["jobs"]] == ["done", "pending", "done"]
    assert s["this_run"] == {"done": 1, "skipped": 0, "failed": 0}
    # A --resume that skips everything still writes the summary.
    (out / "summary.json").unlink()
    assert _run(m, out, "--resume", "--jobs", "0,2").exit_code == 0
    s = _summary(out)
    assert s["done"] == 2 and s["this_run"]["skipped"] == 2


def test_summary_after_a_killed_overwrite_does_not_claim_done(project):
    """The summary written when a run starts marks its jobs pending: a run killed
    before its end leaves a summary that claims only what is on disk."""
    import zcomp_cli.pipeline.batch as batch

    m = _three_jobs(project)
    out = project / "out"
    assert _run(m, out).exit_code == 0
    assert _summary(out)["done"] == 3

    seen = {}

    def killed(*a, **k):
        seen.update(_summary(out))  # what a kill -9 at this moment would leave
        raise SystemExit(137)

    orig = batch._run_planned
    batch._run_planned = killed
    try:
        CliRunner().invoke(cli, ["-q", "composite", str(m), "--out", str(out), "--overwrite"])
    finally:
        batch._run_planned = orig
    assert seen["done"] == 0 and seen["pending"] == 3
    assert all(j["reason"] == "being made" for j in seen["jobs"])
    s = _summary(out)
    # The old outputs are still intact on disk, so they count as done; nothing claims
    # a job of the killed run finished.
    assert all(j["this_run"] is None for j in s["jobs"])


def test_failed_job_stays_failed_in_later_summaries(project):
    doc = base_manifest()
    doc["jobs"].append({"scene": "room", "object": "ball", "pose": {"position": [0, -1, -3]},
                        "shading_radius": 1.0, "output": "broken"})
    (project / "objects/ball/depth.exr").write_bytes(b"broken")
    p = project / "f.yaml"
    p.write_text(yaml.safe_dump(doc))
    out = project / "out"
    r = _run(p, out, "--jobs", "1")
    assert r.exit_code == 0
    r = _run(p, out, "--jobs", "0")
    assert r.exit_code == 1
    s = _summary(out)
    st = {j["name"]: j["status"] for j in s["jobs"]}
    assert st == {"000_room_ball": "failed", "001_room_card": "done", "broken": "pending"}
    r = _run(p, out, "--jobs", "1", "--resume")
    assert {j["name"]: j["status"] for j in _summary(out)["jobs"]}["000_room_ball"] == "failed"


# ------------------------------------------------------------------ locks
def _slow_run(manifest, out, *extra, hold_s=4.0):
    code = ("import time, zcomp_cli.pipeline.batch as b\n"
            "orig = b._run_planned\n"
            f"def slow(*a, **k):\n    print('ready', flush=True); time.sleep({hold_s}); return orig(*a, **k)\n"
            "b._run_planned = slow\n"
            "from zcomp_cli.cli import main\n"
            f"main(['-q', 'composite', {str(manifest)!r}, '--out', {str(out)!r}, *{list(extra)!r}])\n")
    p = subprocess.Popen([sys.executable, "-c", code], env=dict(os.environ, PYTHONPATH=str(SRC)),
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "ready"
    return p


def test_second_run_on_same_jobs_refused_naming_pid(project):
    out = project / "out"
    p = _slow_run(project / "jobs.yaml", out)
    try:
        r = _run(project / "jobs.yaml", out, "--resume")
        assert r.exit_code == 2 and f"pid {p.pid}" in r.output
    finally:
        p.communicate(timeout=60)
    assert p.returncode == 0
    assert not list(out.glob(".zcomp-*")), "lock files left behind"
    assert _run(project / "jobs.yaml", out, "--resume").exit_code == 0


def test_disjoint_jobs_of_one_manifest_run_side_by_side(project):
    """What ``--shard i/n`` does: two runs of one manifest, different jobs, one --out."""
    m = _three_jobs(project)
    out = project / "out"
    p = _slow_run(m, out, "--jobs", "0", hold_s=2.0)
    try:
        r = _run(m, out, "--jobs", "1-2")
        assert r.exit_code == 0, r.output
    finally:
        p.communicate(timeout=60)
    assert p.returncode == 0
    s = _summary(out)
    assert s["done"] == 3, s  # the merged summary has both runs' jobs


def test_another_manifest_into_a_busy_folder_refused(project):
    out = project / "out"
    p = _slow_run(project / "jobs.yaml", out)
    try:
        r = _run(_three_jobs(project), out, "--jobs", "2")
        assert r.exit_code == 2 and "another manifest" in r.output and str(p.pid) in r.output
    finally:
        p.communicate(timeout=60)


def test_lock_of_a_killed_run_is_taken_over(project):
    out = project / "out"
    p = _slow_run(project / "jobs.yaml", out, hold_s=60)
    p.kill()
    p.wait()
    assert list(out.glob(".zcomp-run-*.lock"))  # its lock file is still there
    r = _run(project / "jobs.yaml", out)
    assert r.exit_code == 0, r.output
    assert not list(out.glob(".zcomp-*"))


def test_stale_locks_of_jobs_not_taken_are_removed(project):
    out = project / "out"
    p = _slow_run(project / "jobs.yaml", out, hold_s=60)
    p.kill()
    p.wait()
    r = _run(project / "jobs.yaml", out, "--jobs", "1")  # job 0's stale lock is not ours
    assert r.exit_code == 0, r.output
    assert not list(out.glob(".zcomp-*"))


# ------------------------------------------------------------------ litter
def test_resume_removes_litter_of_killed_runs(project, tmp_path_factory):
    import tempfile

    from zcomp_cli.cache import cache_root

    out = project / "out"
    assert _run(project / "jobs.yaml", out).exit_code == 0
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a pid that is gone
    tmp_job = Path(tempfile.gettempdir()) / f"zcomp-job-{dead.pid}-abc"
    tmp_job.mkdir(exist_ok=True)
    work = cache_root() / "intrinsics" / f".work-{dead.pid}-xyz"
    work.mkdir(parents=True, exist_ok=True)
    live = Path(tempfile.gettempdir()) / f"zcomp-job-{os.getpid()}-live"
    live.mkdir(exist_ok=True)
    tmp_png = out / "000_room_ball" / ".composite.k2j3.tmp.png"
    tmp_png.write_bytes(b"half")
    # OUT/lights is shared by runs side by side: a dead writer's temporary goes, a live
    # one's (this process: imageio.atomic_path's name carries the writer's pid) stays
    (out / "lights").mkdir(exist_ok=True)
    dead_light = out / "lights" / f".room.{dead.pid}-q1w2e3.tmp.yaml"
    live_light = out / "lights" / f".room.{os.getpid()}-r4t5y6.tmp.yaml"
    dead_light.write_text("half")
    live_light.write_text("half")
    try:
        r = _run(project / "jobs.yaml", out, "--resume")
        assert r.exit_code == 0
        assert not tmp_job.exists() and not work.exists() and not tmp_png.exists()
        assert not dead_light.exists(), "a killed writer's light temporary was left"
        assert live_light.exists(), "a live writer's light temporary was removed"
        assert live.exists(), "a live process's temporary folder was removed"
    finally:
        live_light.unlink(missing_ok=True)
        shutil.rmtree(live, ignore_errors=True)


# ------------------------------------------------------------------ intrinsics cache
def test_cache_entries_verified_and_delivered_as_copies(tmp_path):
    from zcomp_cli.blender import cache as bcache
    from zcomp_cli.camera import Camera
    from zcomp_cli.testing import sphere_object_bundle

    cam = Camera.from_fov(50, 16, 12)
    b = sphere_object_bundle(cam, center=(0, 0, -3), radius=0.5)
    work = tmp_path / "work"
    b.save(work)
    entry = bcache.store(tmp_path / "cache", "ab" * 32, work)
    assert bcache.lookup(tmp_path / "cache", "ab" * 32) == entry
    out = tmp_path / "out"
    bcache.copy_bundle(entry, out)
    assert os.stat(out / "depth.exr").st_ino != os.stat(entry / "depth.exr").st_ino
    assert not (out / bcache.HASHES).exists()
    (out / "depth.exr").write_bytes(b"edited")  # editing the delivered copy ...
    assert bcache.lookup(tmp_path / "cache", "ab" * 32) == entry  # ... leaves the cache intact
    (entry / "albedo.exr").write_bytes(b"damaged")
    assert bcache.lookup(tmp_path / "cache", "ab" * 32) is None  # a damaged entry is dropped
    assert not entry.exists()


def test_two_shards_at_once_into_one_out(project):
    """``--shard`` runs of one manifest hold disjoint job locks: they run side by side;
    a second copy of the same shard is refused."""
    m = _three_jobs(project)
    out = project / "out"
    p = _slow_run(m, out, "--shard", "0/2", hold_s=3.0)
    try:
        r = _run(m, out, "--shard", "1/2")
        assert r.exit_code == 0, r.output
        r = _run(m, out, "--shard", "0/2")
        assert r.exit_code == 2 and f"pid {p.pid}" in r.output
    finally:
        p.communicate(timeout=60)
    assert p.returncode == 0
    st = CliRunner().invoke(cli, ["status", str(out), "--json"])
    d = json.loads(st.output)
    assert d["done"] == 3 and d["complete"], d


def test_out_probe_of_a_new_folder_touches_nothing(tmp_path):
    """The --out probe must not create (then remove) the folder itself: two shards
    starting together into one new --out raced on that and one failed with "File exists"
    (seen in benchmarks/bench_scaleout.py)."""
    from concurrent.futures import ThreadPoolExecutor

    from zcomp_cli.cli.options import check_writable_dir

    out = tmp_path / "new" / "out"
    assert check_writable_dir(out) is None
    assert not (tmp_path / "new").exists() and list(tmp_path.iterdir()) == []
    (tmp_path / "new").mkdir()
    with ThreadPoolExecutor(8) as pool:  # many probes at once, while the folder appears
        results = list(pool.map(lambda i: check_writable_dir(out) if i % 2 else out.mkdir(exist_ok=True),
                                range(64)))
    assert all(r is None for r in results)
    assert [p.name for p in (tmp_path / "new").iterdir()] == ["out"] and list(out.iterdir()) == []


def test_exr_bytes_do_not_depend_on_the_write_time(tmp_path):
    import time

    from zcomp_cli.imageio import write_exr

    img = np.linspace(0, 1, 4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    write_exr(tmp_path / "a.exr", img)
    time.sleep(1.05)  # the header's DateTime has a one-second resolution
    write_exr(tmp_path / "b.exr", img)
    assert (tmp_path / "a.exr").read_bytes() == (tmp_path / "b.exr").read_bytes()
