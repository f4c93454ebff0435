"""Scale-out: --shard partitions, `zcomp status` over shards, and the Ray executor
(a local Ray with 2 CPUs). Mesh-free jobs (2D card objects, analytic scenes given as
maps), so nothing here needs Blender."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from zcomp_cli.cli import cli
from zcomp_cli.errors import UsageError
from zcomp_cli.pipeline.manifest import load_manifest
from zcomp_cli.pipeline.selection import parse_shard, shard_jobs
from zcomp_cli.testing import write_floor_batch



def _composite(*args):
    return CliRunner().invoke(cli, ["-q", "composite", *map(str, args)], catch_exceptions=False)


def _outputs(out: Path) -> dict[str, bytes]:
    """Every job's composite.png and composite.exr bytes (EXRs carry no write time, so
    whole files match across runs)."""
    got = {}
    for d in sorted(p for p in out.iterdir() if (p / "report.json").is_file()):
        if (d / "composite.png").exists():
            got[f"{d.name}/composite.png"] = (d / "composite.png").read_bytes()
        if (d / "composite.exr").exists():
            got[f"{d.name}/composite.exr"] = (d / "composite.exr").read_bytes()
    return got


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    return write_floor_batch(tmp_path_factory.mktemp("batch"), 7, n_scenes=3)


@pytest.fixture(scope="module")
def local_run(batch, tmp_path_factory):
    out = tmp_path_factory.mktemp("local") / "out"
    res = _composite(batch, "--out", out)
    assert res.exit_code == 0, res.output
    return out


# ------------------------------------------------------------------------------------
# shards
# ------------------------------------------------------------------------------------
def test_parse_shard():
    assert parse_shard(None) is None and parse_shard("2/3") == (2, 3)
    for bad in ("3/3", "-1/3", "1/0", "a/b", "1", "1/2/3"):
        with pytest.raises(UsageError):
            parse_shard(bad)


def test_shards_partition_and_keep_scenes_together(batch):
    jobs = load_manifest(batch).jobs
    for n in (1, 2, 3, 5, 9):
        parts = [shard_jobs(jobs, i, n) for i in range(n)]
        names = [j.name for p in parts for j in p]
        assert sorted(names) == sorted(j.name for j in jobs), n  # every job exactly once
        assert parts == [shard_jobs(jobs, i, n) for i in range(n)]  # deterministic
        cap = -(-len(jobs) // n)
        assert max(len(p) for p in parts) <= cap + 2, n  # balanced
    # 3 shards of 3 scenes: one scene per shard
    assert all(len({j.scene for j in shard_jobs(jobs, i, 3)}) == 1 for i in range(3))
    # a scene bigger than its share is split, so no shard idles
    one_scene = [j for j in jobs if j.scene == "s0"]
    assert all(shard_jobs(one_scene, i, 2) for i in range(2))


@pytest.mark.slow
def test_three_shards_equal_the_whole_run_and_status_merges(batch, local_run, tmp_path):
    out = tmp_path / "out"
    for i in range(3):
        res = _composite(batch, "--out", out, "--shard", f"{i}/3")
        assert res.exit_code == 0, res.output
        assert (out / f"summary.shard-{i}-of-3.json").is_file()
    assert _outputs(out) == _outputs(local_run)
    st = CliRunner().invoke(cli, ["status", str(out), "--json"])
    assert st.exit_code == 0, st.output
    d = json.loads(st.output)
    assert d["done"] == 7 and d["failed"] == 0 and d["missing"] == 0 and d["complete"]
    assert d["shards"] == {"0/3": "finished", "1/3": "finished", "2/3": "finished"}
    # a resumed shard skips its finished jobs
    res = _composite(batch, "--out", out, "--shard", "1/3", "--resume")
    assert res.exit_code == 0
    summ = json.loads((out / "summary.shard-1-of-3.json").read_text())
    # counts: "done" is the folder's state for the shard's jobs, "this_run" what this run did
    assert summ["skipped"] == len(summ["shard"]["jobs"]) and summ["this_run"]["done"] == 0
    assert summ["done"] == len(summ["shard"]["jobs"])


@pytest.mark.slow
def test_status_reports_missing_and_failed(batch, tmp_path):
    out = tmp_path / "out"
    assert _composite(batch, "--out", out, "--shard", "0/3").exit_code == 0
    st = CliRunner().invoke(cli, ["status", str(out), "--json"])
    d = json.loads(st.output)
    assert st.exit_code == 1 and d["shards"]["1/3"] == "no summary" and d["done"] >= 2
    # with the manifest, the jobs of the shards that never ran are missing
    st = CliRunner().invoke(cli, ["status", str(out), "--manifest", str(batch), "--json"])
    d = json.loads(st.output)
    assert d["done"] + d["missing"] == 7 and d["missing"] >= 4
    # a failed job keeps its reason
    summ = json.loads((out / "summary.shard-0-of-3.json").read_text())
    name = summ["jobs"][0]["name"]
    summ["jobs"][0].update(status="failed", reason="boom: disk full")
    (out / name / "report.json").unlink()
    (out / "summary.shard-0-of-3.json").write_text(json.dumps(summ))
    d = json.loads(CliRunner().invoke(cli, ["status", str(out), "--json"]).output)
    assert d["jobs"]["failed"] == {name: "boom: disk full"}
    plain = CliRunner().invoke(cli, ["status", str(out)])
    assert plain.exit_code == 1 and "boom: disk full" in plain.output


# ------------------------------------------------------------------------------------
# Ray
# ------------------------------------------------------------------------------------
def test_plain_install_names_the_extra(no_ray, batch, tmp_path):
    no_ray()
    res = CliRunner().invoke(cli, ["composite", str(batch), "--out", str(tmp_path / "o"), "--executor", "ray"])
    assert res.exit_code == 2 and "zcomp[ray]" in res.output
    res = CliRunner().invoke(cli, ["composite", str(batch), "--out", str(tmp_path / "o"), "--workers", "2"])
    assert res.exit_code == 2 and "--executor ray" in res.output


@pytest.fixture(scope="module")
def ray_local():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


@pytest.mark.slow
def test_ray_gives_the_local_outputs_byte_for_byte(ray_local, batch, local_run, tmp_path):
    out = tmp_path / "out"
    res = _composite(batch, "--out", out, "--executor", "ray", "--workers", "2")
    assert res.exit_code == 0, res.output
    assert _outputs(out) == _outputs(local_run)
    summ = json.loads((out / "summary.json").read_text())
    assert summ["done"] == 7 and summ["executor"]["name"] == "ray" and summ["executor"]["workers"] == 2
    assert not list(out.glob(".zcomp-probe-*"))  # the shared-folder probe is cleaned up


@pytest.mark.slow
def test_ray_worker_killed_mid_batch_every_job_done_once(ray_local, batch, local_run, tmp_path, monkeypatch):
    from zcomp_cli.pipeline.manifest import load_manifest as _load
    from zcomp_cli.pipeline.batch import run_batch
    from zcomp_cli.pipeline.ray_executor import KILL_ONCE_ENV, RayExecutor

    marker = tmp_path / "killed"
    # Ray workers are forked by the raylet started in ray_local, which does not see
    # this process's later environment: pass the hook through the actor's runtime env.
    ex = RayExecutor(workers=2, runtime_env={"env_vars": {KILL_ONCE_ENV: str(marker)}})
    summary = run_batch(_load(batch), tmp_path / "out", executor=ex)
    assert marker.exists()  # a worker did die after finishing a job
    names = [s.job.name for s in summary.statuses]
    assert sorted(names) == sorted(set(names)) and len(names) == 7  # each job once
    assert all(s.status == "done" for s in summary.statuses), [s.reason for s in summary.statuses]
    # the dead worker's unit was finished by another process (Ray restarted the actor)
    killed = int(marker.read_text())
    assert killed not in summary.executor["worker_pids"] and len(summary.executor["worker_pids"]) >= 1
    assert _outputs(tmp_path / "out") == _outputs(local_run)


@pytest.mark.slow
def test_ray_refuses_an_output_folder_a_node_cannot_see(ray_local, batch, tmp_path, monkeypatch):
    from zcomp_cli.pipeline.ray_executor import RayExecutor

    ex = RayExecutor()
    ex._ray = ray_local

    # simulate a node that does not see the folder: the probe vanishes before it is read
    def write_elsewhere(self, data, *a, **k):
        return len(data)

    monkeypatch.setattr(Path, "write_text", write_elsewhere)
    with pytest.raises(UsageError, match="not visible from every Ray node"):
        ex._check_shared_output(tmp_path)


@pytest.mark.slow
@pytest.mark.blender
def test_ray_renders_meshes_in_its_workers_like_a_local_run(ray_local, small_example, tmp_path):
    """Mesh jobs: each Ray worker renders its units' objects in its own kept Blender
    process (BlenderSession); the composites match a local run's."""
    pytest.importorskip("bpy")
    manifest = small_example(tmp_path, jobs=[0, 1, 2])
    local, remote = tmp_path / "local", tmp_path / "ray"
    r = _composite(manifest, "--out", local, "--renderer", "naive")
    assert r.exit_code == 0, r.output
    # a cache of its own, so that the worker does render (not reuse the local run's)
    r = _composite(manifest, "--out", remote, "--renderer", "naive", "--executor", "ray", "--workers", "1",
                   "--cache-dir", tmp_path / "cache")
    assert r.exit_code == 0, r.output
    assert list((tmp_path / "cache").rglob("meta.json"))  # the worker rendered the objects
    assert _outputs(remote) == _outputs(local) and len(_outputs(local)) == 6


def test_ray_workers_get_their_share_of_the_cpus():
    """A worker asks Ray for its share of the cluster's cores (Ray sets its thread count
    from it: one worker used to be limited to one thread), never more than a node
    holds, and all the workers must fit on the nodes."""
    from zcomp_cli.pipeline.ray_executor import cpus_per_worker

    assert cpus_per_worker([2], 1) == 2 and cpus_per_worker([2], 2) == 1 and cpus_per_worker([4], 8) == 1
    assert cpus_per_worker([16, 16, 16, 16], 4) == 16 and cpus_per_worker([16, 16], 8) == 4
    assert cpus_per_worker([10, 6], 2) == 6  # 8 each would leave the second worker nowhere to go
    assert cpus_per_worker([], 3) == 1

