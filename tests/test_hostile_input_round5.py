"""Hostile input, round 5 (issue 50): one test per attack, through the real CLI, each
failing before its fix. Mesh-free project (``hostile_project``), naive renderer: each
test takes a second or two."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from hostile_project import make_project, run_composite
from zcomp_cli.cli import cli

SRC = Path(__file__).resolve().parents[1] / "src"
# An upper bound for a child that must end by itself (a FIFO made it wait forever): it
# returns as soon as the child does.
CHILD_BOUND_S = 300


@pytest.fixture
def project(tmp_path):
    make_project(tmp_path)
    return tmp_path


def _zcomp(*args, memory_bytes: int | None = None) -> subprocess.CompletedProcess:
    """``zcomp ARGS`` in a child (``memory_bytes``: its address-space limit)."""
    def limit():
        if memory_bytes:
            resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))

    r = subprocess.run([sys.executable, "-m", "zcomp_cli", *map(str, args)], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(SRC)), timeout=CHILD_BOUND_S, preexec_fn=limit)
    assert "Traceback" not in r.stderr + r.stdout, r.stderr[-3000:]
    return r


def _done(project: Path) -> Path:
    out = project / "out"
    r = run_composite(project / "jobs.yaml", out)
    assert r.exit_code == 0, r.output
    return out


# ------------------------------------------------------------------ defect 4: special files
@pytest.mark.parametrize("name", ["summary.json", "summary.shard-1-of-2.json"])
@pytest.mark.parametrize("kind", ["fifo", "dev-zero"])
def test_a_special_file_as_summary_is_not_read(project, name, kind):
    """A FIFO named like a summary made ``status``, ``report`` and ``composite --out``
    wait forever; one linked to /dev/zero was read until memory ran out. Now each is
    skipped with a note (the children run under a 2 GB address space)."""
    out = _done(project)
    p = out / name
    p.unlink(missing_ok=True)
    if kind == "fifo":
        os.mkfifo(p)
    else:
        p.symlink_to("/dev/zero")
    st = _zcomp("status", out, "--json", memory_bytes=2 << 30)
    assert st.returncode == 0, st.stderr
    doc = json.loads(st.stdout)
    assert doc["done"] == 2 and any(name in n and "not a regular file" in n for n in doc["notes"]), doc["notes"]
    rep = _zcomp("report", out, memory_bytes=2 << 30)
    assert rep.returncode == 0, rep.stderr
    comp = _zcomp("-q", "composite", project / "jobs.yaml", "--out", out, "--resume", memory_bytes=4 << 30)
    assert comp.returncode == 0, comp.stderr


# ------------------------------------------------------------------ defect 5: deep JSON
DEEP = "[" * 100_000 + "]" * 100_000  # 200 kB


@pytest.mark.parametrize("where", ["000_room_ball/report.json", "summary.json", "eval.json", "preview/room.json"])
def test_deeply_nested_json_in_out_counts_as_damaged(project, where):
    """100 000 nested arrays in any JSON file of OUT gave a RecursionError traceback and
    stopped ``composite --resume`` for every job, ``status`` and ``report``. Now the file
    counts as missing (a report: its job is redone), with a note."""
    out = _done(project)
    p = out / where
    p.parent.mkdir(exist_ok=True)
    if where.startswith("preview/"):
        from zcomp_cli.report.synthetic import tiny_png

        (out / "preview" / "room.png").write_bytes(tiny_png((9, 9, 9)))
    p.write_text(DEEP)
    st = CliRunner().invoke(cli, ["status", str(out), "--json"])
    assert st.exit_code in (0, 1) and st.exception is None or isinstance(st.exception, SystemExit), st.exc_info
    doc = json.loads(st.output)
    rep = CliRunner().invoke(cli, ["report", str(out)])
    assert rep.exit_code == 0 and rep.exception is None or isinstance(rep.exception, SystemExit), rep.exc_info
    r = run_composite(project / "jobs.yaml", out, "--resume")
    assert r.exit_code == 0, r.output
    this_run = {j["name"]: j["this_run"] for j in json.loads((out / "summary.json").read_text())["jobs"]}
    if where.endswith("report.json"):
        assert doc["missing"] == 1 and any("report.json" in n for n in doc["notes"])
        assert this_run == {"000_room_ball": "done", "001_room_card": "skipped"}
    else:
        assert this_run == {"000_room_ball": "skipped", "001_room_card": "skipped"}
    if where == "summary.json":
        assert any("summary.json" in n and "nested" in n for n in doc["notes"]), doc["notes"]


# ------------------------------------------------------------------ where it came from
CHEAP_PHYSICAL = {"name": "physical", "march_steps": 4, "estimate_march_steps": 4, "n_light_candidates": 16,
                  "cone_samples": 2, "max_fit_pixels": 500}


def test_no_light_is_read_off_shadows_when_none_were_read(tmp_path):
    """Issue 50 (the coffee photograph): the preview and the report said the direction
    was "read off the photograph's cast shadows" where the fit read no shadow. On a
    bare floor (no shadow at all), the direction comes from the shading's fit."""
    import yaml

    p = make_project(tmp_path, width=64, height=48)
    doc = yaml.safe_load(p.read_text())
    doc["defaults"]["renderer"] = CHEAP_PHYSICAL
    doc["jobs"] = doc["jobs"][:1]
    p.write_text(yaml.safe_dump(doc))
    assert run_composite(p, tmp_path / "out").exit_code == 0
    light = json.loads((tmp_path / "out/000_room_ball/report.json").read_text())["renderer"]["info"]["light"]
    assert light["fit"]["shadow_blocks"] == 0
    sun = next(x for x in light["lights"] if x["kind"] == "sun")
    assert sun["direction_from"] != "read off the photograph's cast shadows"
    assert sun["direction_from"] == "fitted to the photograph's shading"
