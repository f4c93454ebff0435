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


# ------------------------------------------------------------------ preview-light
def _preview(project: Path, out: Path, *extra):
    r = CliRunner().invoke(cli, ["-q", "preview-light", str(project / "jobs.yaml"), "--out", str(out),
                                 *map(str, extra)])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exc_info
    return r


def test_preview_refuses_a_linked_preview_folder(project, tmp_path):
    """Defect 3: preview-light followed a symlinked OUT/preview and wrote (with
    --overwrite, replaced) files outside --out; every other command refuses it."""
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    out.mkdir()
    elsewhere.mkdir()
    (elsewhere / "room.png").write_bytes(b"precious")
    (out / "preview").symlink_to(elsewhere)
    for extra in ([], ["--overwrite"]):
        r = _preview(project, out, *extra)
        assert r.exit_code == 2 and "symbolic link" in r.output, r.output
    assert sorted(p.name for p in elsewhere.iterdir()) == ["room.png"]
    assert (elsewhere / "room.png").read_bytes() == b"precious"


def test_preview_renders_a_repeated_scene_once(project, tmp_path, monkeypatch):
    from zcomp_cli.preview import run as prun

    seen = []
    monkeypatch.setattr(prun, "preview_scene", lambda m, name, *a, **k: seen.append(name) or prun.PreviewResult(name))
    r = _preview(project, tmp_path / "out", "--scene", "room", "--scene", "room")
    assert r.exit_code == 0, r.output
    assert seen == ["room"]


def test_a_second_preview_run_into_the_folder_is_refused(project, tmp_path, monkeypatch):
    """Two runs into one --out replaced each other's sheets without --overwrite: the
    second is refused while the first holds the folder."""
    from zcomp_cli.pipeline.outguard import held_or_refused
    from zcomp_cli.preview import run as prun

    out = tmp_path / "out"
    (out / "preview").mkdir(parents=True)
    seen = []
    monkeypatch.setattr(prun, "preview_scene", lambda m, name, *a, **k: seen.append(name) or prun.PreviewResult(name))
    with held_or_refused(out / "preview" / ".zcomp-preview.lock", "zcomp preview-light"):
        r = _preview(project, out)
    assert r.exit_code == 2 and f"pid {os.getpid()}" in r.output, r.output
    assert seen == []
    assert _preview(project, out).exit_code == 0 and seen == ["room"]  # free again


@pytest.mark.parametrize("diameter, words", [("1e-9", "too small to see"), ("50", "larger than the")])
def test_preview_names_a_diameter_too_small_or_too_large(project, tmp_path, diameter, words):
    """Defect (preview-light): --diameter 1e-9 and 50 both said "the object lies fully
    outside the frame"."""
    r = _preview(project, tmp_path / "out", "--diameter", diameter)
    text = " ".join(r.output.split())
    assert r.exit_code == 1 and words in text and "give --diameter" in text, r.output
    assert "fully outside" not in r.output


def test_preview_of_a_surface_1e30_away_is_refused_with_a_note(project, tmp_path):
    """A scene depth of 1e30 gave a blank sheet with no note."""
    import numpy as np

    from zcomp_cli.imageio import read_map, write_exr

    d = read_map(project / "scenes/depth.exr", channels=1)
    write_exr(project / "scenes/depth.exr", np.where(d > 0, np.float32(1e30), d).astype(np.float32))
    out = tmp_path / "out"
    r = _preview(project, out)
    assert r.exit_code == 1 and "1e+30 m away" in " ".join(r.output.split()), r.output
    assert not list((out / "preview").glob("*.png"))


def test_a_killed_previews_work_folder_is_swept(tmp_path):
    """kill -9 of preview-light left /tmp/zcomp-preview-* that nothing swept."""
    import tempfile

    from zcomp_cli.pipeline.outguard import sweep_dead_temporaries
    from zcomp_cli.preview.run import WORK_PREFIX

    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    dead = Path(tempfile.mkdtemp(prefix=f"{WORK_PREFIX}{child.pid}-"))
    mine = Path(tempfile.mkdtemp(prefix=f"{WORK_PREFIX}{os.getpid()}-"))
    (dead / "balls.glb").write_bytes(b"x")
    try:
        sweep_dead_temporaries()
        assert not dead.exists() and mine.exists()
    finally:
        import shutil

        shutil.rmtree(dead, ignore_errors=True)
        shutil.rmtree(mine, ignore_errors=True)


@pytest.mark.blender
def test_sigterm_between_a_sheet_and_its_numbers_leaves_both_or_neither(tmp_path, monkeypatch):
    """A SIGTERM that arrived between a sheet's PNG and its JSON left half a pair."""
    import signal

    import zcomp_cli.imageio as io

    make_project(tmp_path, width=128, height=96)
    real = io.write_json_atomic

    def term_then_write(path, obj):
        if Path(path).suffix == ".json" and Path(path).parent.name == "preview":
            os.kill(os.getpid(), signal.SIGTERM)
        return real(path, obj)

    monkeypatch.setattr(io, "write_json_atomic", term_then_write)
    out = tmp_path / "out"
    r = _preview(tmp_path, out, "--samples", "4")
    assert r.exit_code == 143, r.output
    names = sorted(p.name for p in (out / "preview").iterdir() if not p.name.startswith("."))
    assert names in ([], ["room.json", "room.png"]), names


# ------------------------------------------------------------------ cycles settings
@pytest.mark.parametrize("setting, value", [("samples", ".inf"), ("max_bounces", ".inf"), ("samples", "1e30"),
                                            ("sky_width", "8192"), ("probe_width", "100000"),
                                            ("threads", "-.inf")])
def test_cycles_settings_out_of_bounds_are_refused_naming_the_field(project, tmp_path, setting, value):
    """`samples: .inf` gave an OverflowError traceback, `samples: 1e30` passed and failed
    every job in Blender, `sky_width: 8192` peaked at 4 GB."""
    text = (project / "jobs.yaml").read_text().replace(
        "renderer: naive", f"renderer: {{name: cycles, {setting}: {value}}}")
    (project / "m.yaml").write_text(text)
    r = run_composite(project / "m.yaml", tmp_path / "out")
    assert r.exit_code == 2 and "defaults.renderer" in r.output and setting in r.output, r.output
    assert not (tmp_path / "out").exists()


def test_cycles_samples_flag_is_bounded(project, tmp_path):
    r = run_composite(project / "jobs.yaml", tmp_path / "out", "--renderer", "cycles", "--samples", "1000000000")
    assert r.exit_code == 2 and "samples" in r.output and "4096" in r.output, r.output


# ------------------------------------------------------------------ flipped normals
@pytest.mark.parametrize("which", ["scene", "bundle"])
def test_normals_facing_away_are_named_not_blamed_on_a_plugin(project, tmp_path, which):
    """Normals that all face away from the camera made the built-in renderer return
    2.1e6 and the job's reason blamed "a plugin's bug". The flipped frame is named,
    with the file, as the importer does."""
    import numpy as np
    import yaml

    from zcomp_cli.imageio import read_map, write_exr

    path = project / ("scenes/normals.exr" if which == "scene" else "objects/ball/normals.exr")
    write_exr(path, (-read_map(path, channels=3)).astype(np.float32))
    doc = yaml.safe_load((project / "jobs.yaml").read_text())
    doc["defaults"]["renderer"] = CHEAP_PHYSICAL
    doc["jobs"] = doc["jobs"][:1]
    (project / "m.yaml").write_text(yaml.safe_dump(doc))
    r = run_composite(project / "m.yaml", tmp_path / "out")
    assert r.exit_code == 1, r.output
    text = json.loads((tmp_path / "out/summary.json").read_text())["jobs"][0]["reason"]
    assert "face away from the camera" in text and "normals.exr" in text, text
    assert "plugin" not in text


def test_a_builtin_renderers_impossible_output_is_not_called_a_plugins_bug():
    from zcomp_cli.pipeline import job

    assert "plugin" not in job._whose_bug("physical") and "report" in job._whose_bug("physical")
    assert job._whose_bug("toon") == "a plugin's bug"


# ------------------------------------------------------------------ negative pixels
@pytest.mark.parametrize("level", [1.0, 2.0 ** 20])
def test_negative_pixels_are_kept_outside_the_edited_region(tmp_path, level):
    """A photograph with negative pixels (an EXR, graded or denoised) was clamped to 0
    everywhere, so the composite's background differed from the photograph outside the
    edited region. Now it is bit for bit the photograph there, with a note; also for a
    photograph worked at another level (``Scene.working_scale``, issue 49: 2^20 is
    outside its range), whose kept pixels are put back after the output is scaled."""
    import numpy as np
    import yaml

    from zcomp_cli.imageio import read_image, write_exr

    project = tmp_path / "p"
    make_project(project, width=128, height=96)
    img = read_image(project / "scenes/room.png")
    img[:4, :4] = -0.25  # the top-left corner: far from the ball
    img[-1, -1] = -1e-3
    img *= np.float32(level)  # (a power of two: exact)
    write_exr(project / "scenes/room.exr", img)
    doc = yaml.safe_load((project / "jobs.yaml").read_text())
    doc["scenes"]["room"]["image"] = "scenes/room.exr"
    doc["jobs"] = doc["jobs"][:1]
    (project / "m.yaml").write_text(yaml.safe_dump(doc))
    out = tmp_path / "out"
    assert run_composite(project / "m.yaml", out).exit_code == 0
    comp = read_image(out / "000_room_ball/composite.exr")
    rep = json.loads((out / "000_room_ball/report.json").read_text())
    x0, y0, x1, y1 = rep["roi"]["box"]
    far = np.ones(img.shape[:2], bool)
    far[y0:y1, x0:x1] = False
    assert far[:4, :4].all()
    assert np.array_equal(comp[far], img[far])
    assert any("negative" in n for n in json.dumps(rep).split('"') if "pixels of the photograph" in n)
    assert (rep.get("working_scale", 1.0) != 1.0) == (level != 1.0)


# ------------------------------------------------------------------ -v
BOOM = """
import sys
import zcomp_cli.renderers.naive as naive

def boom(self, requests, **kw):
    raise RuntimeError("boom in the renderer")

naive.NaiveRenderer.render = boom
from zcomp_cli.cli import main
main(sys.argv[1:])
"""


@pytest.mark.parametrize("verbose", [False, True])
def test_v_shows_a_jobs_internal_error_traceback(project, tmp_path, verbose):
    """-v showed no traceback for a job's internal error (only -vv did), where the
    README says -v does; without -v there is none."""
    args = (["-v"] if verbose else []) + ["composite", str(project / "jobs.yaml"), "--out", str(tmp_path / "out")]
    r = subprocess.run([sys.executable, "-c", BOOM, *args], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(SRC)), timeout=CHILD_BOUND_S)
    assert r.returncode == 1, r.stderr
    text = r.stdout + r.stderr
    reasons = [j["reason"] for j in json.loads((tmp_path / "out/summary.json").read_text())["jobs"]]
    assert reasons == ["internal error: RuntimeError: boom in the renderer"] * 2
    assert ("Traceback" in text) is verbose, text[-2000:]
    if verbose:
        assert "in boom" in text and "RuntimeError: boom in the renderer" in text


# ------------------------------------------------------------------ report and status on hostile OUT
def _failed_summary(out: Path, jobs: list[tuple[str, str]]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / "summary.json").write_text(json.dumps({"jobs": [
        {"index": i, "name": n, "status": "failed", "reason": r, "seconds": 0.1, "this_run": "failed"}
        for i, (n, r) in enumerate(jobs)]}))


@pytest.mark.parametrize("case", ["long-name", "non-utf8-folder", "empty-eval-csv", "huge-csv-field"])
def test_report_and_status_survive_hostile_out_content(tmp_path, case):
    """`report` gave tracebacks on a job name over 255 bytes, non-UTF-8 folder names, an
    empty eval.csv and a CSV field over 128 KB."""
    out = tmp_path / "out"
    _failed_summary(out, [("plain", "x")] + ([("a" * 300, "too long a name")] if case == "long-name" else []))
    if case == "non-utf8-folder":
        bad = Path(os.fsdecode(bytes(out) + b"/job\xff"))
        bad.mkdir()
        (bad / "report.json").write_text('{"status": "done", "outputs": {}}')
    if case == "empty-eval-csv":
        (out / "eval.csv").write_text("")
    if case == "huge-csv-field":
        (out / "eval.csv").write_text("name,pred,ref,psnr\nplain,a,b," + "9" * 200_000 + "\n")
    rep = _zcomp("report", out)
    assert rep.returncode == 0, rep.stderr
    page = (out / "report.html").read_text(encoding="utf-8")  # valid UTF-8
    if case == "non-utf8-folder":  # shown escaped (the folder's bytes cannot be UTF-8 text)
        data = json.loads(re_blob(page))
        k = [c["key"] for c in data["columns"]].index("job")
        assert "job\\udcff" in [r[k] for r in data["rows"]]
    if case.endswith("csv"):
        assert "eval.csv" in page and "no metrics shown" in page
    st = subprocess.run([sys.executable, "-m", "zcomp_cli", "status", str(out)], capture_output=True,
                        env=dict(os.environ, PYTHONPATH=str(SRC)), timeout=CHILD_BOUND_S)
    assert st.returncode == 1 and b"Traceback" not in st.stderr
    st.stdout.decode("utf-8")  # (raw undecodable bytes made it invalid UTF-8)


def test_a_huge_failure_reason_is_cut_when_shown(tmp_path):
    """A 100 MB failure reason made a 600 MB page, and `status` printed it for minutes:
    every displayed field is cut (here 20 MB)."""
    out = tmp_path / "out"
    _failed_summary(out, [("plain", "y" * 20_000_000)])
    rep = _zcomp("report", out)
    assert rep.returncode == 0 and (out / "report.html").stat().st_size < 200_000
    st = _zcomp("status", out)
    assert st.returncode == 1 and len(st.stdout) < 20_000 and "more characters" in st.stdout


def test_a_huge_failure_reason_is_cut_when_written(project, tmp_path):
    """A renderer's 1 MB exception message is written to the summary cut."""
    boom = BOOM.replace('raise RuntimeError("boom in the renderer")', 'raise RuntimeError("z" * 1_000_000)')
    r = subprocess.run([sys.executable, "-c", boom, "-q", "composite", str(project / "jobs.yaml"), "--out",
                        str(tmp_path / "out")], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(SRC)), timeout=CHILD_BOUND_S)
    assert r.returncode == 1 and len(r.stdout + r.stderr) < 50_000
    reasons = [j["reason"] for j in json.loads((tmp_path / "out/summary.json").read_text())["jobs"]]
    assert all(len(x) < 3000 and x.endswith("more characters)") for x in reasons), [len(x) for x in reasons]


def test_a_job_folder_linked_outside_is_not_done(project, tmp_path):
    """`status` and `report` counted a job folder that is a symbolic link to outside
    as done (composite refuses it)."""
    import shutil

    out = _done(project)
    elsewhere = tmp_path / "elsewhere"
    shutil.move(out / "000_room_ball", elsewhere)
    (out / "000_room_ball").symlink_to(elsewhere)
    st = _zcomp("status", out, "--json")
    doc = json.loads(st.stdout)
    assert st.returncode == 1 and "000_room_ball" in doc["jobs"]["damaged"]
    assert "symbolic link" in doc["jobs"]["damaged"]["000_room_ball"]
    assert _zcomp("report", out).returncode == 0
    rows = json.loads(re_blob((out / "report.html").read_text()))
    assert "done" not in [r[6] for r in rows["rows"] if r[2] == "000_room_ball"]


def re_blob(page: str) -> str:
    import re

    return re.search(r'<script id="zcomp-data" type="application/json">(.*?)</script>', page, re.S).group(1)


# ------------------------------------------------------------------ ground plane
@pytest.mark.parametrize("depth, key", [("{proxy: ground_plane, camera_height: 1.5, pitch_deg: -90}", "pitch_deg"),
                                        ("{proxy: ground_plane, camera_height: 1.5, roll_deg: 50, pitch_deg: 5}",
                                         "roll_deg"),
                                        ("{proxy: ground_plane, camera_height: 1.5}", None)])
def test_a_ground_plane_the_estimator_refuses_is_refused_at_validation(project, tmp_path, depth, key):
    """`pitch_deg: -90` passed validation; `zcomp estimate` then aborted the whole run at
    that scene. Now the manifest is refused with the line and the field, nothing run."""
    text = (project / "jobs.yaml").read_text().replace("depth: scenes/depth.exr", f"depth: {depth}")
    (project / "m.yaml").write_text(text)
    for cmd in (["estimate", str(project / "m.yaml"), "--out", str(tmp_path / "est")],
                ["composite", str(project / "m.yaml"), "--out", str(tmp_path / "out")]):
        r = CliRunner().invoke(cli, cmd)
        assert r.exit_code == 2 and "m.yaml:" in r.output and "depth" in r.output, r.output
        if key:
            assert key in r.output
        assert "Traceback" not in r.output
    assert not (tmp_path / "est").exists() and not (tmp_path / "out").exists()


# ------------------------------------------------------------------ chrome ball
@pytest.mark.parametrize("fmt, hdr", [("float", True), ("uint16", False), ("uint8", False)])
def test_a_chrome_balls_range_is_decided_by_its_pixels_not_its_name(tmp_path, fmt, hdr):
    """A chrome ball in a 32-bit float TIFF was called LDR (its suffix is not .exr):
    its sun counted as clipped, the sheet said 8/16-bit."""
    import numpy as np
    import OpenImageIO as oiio

    from zcomp_cli.chromeball import read_ball

    img = np.full((32, 32, 3), 0.25, np.float32)
    img[10:12, 10:12] = 40.0  # a sun, far above 1
    p = str(tmp_path / "ball.tif")
    out = oiio.ImageOutput.create(p)
    kind = {"float": oiio.FLOAT, "uint16": oiio.UINT16, "uint8": oiio.UINT8}[fmt]
    assert out.open(p, oiio.ImageSpec(32, 32, 3, kind))
    out.write_image(img if fmt == "float" else np.clip(img, 0, 1))
    out.close()
    got, is_hdr = read_ball(p)
    assert is_hdr is hdr
    if hdr:
        assert got.max() == pytest.approx(40.0)


# ------------------------------------------------------------------ planning a big mesh
def test_a_dense_mesh_is_judged_per_pose_by_few_points(tmp_path):
    """1000 jobs on one 48 MB OBJ planned for 66 s: every pose transformed and projected
    all its vertices. Per pose only the extent's few points are used now; every pixel
    box holds the whole mesh's image (exact where the hull is small)."""
    import numpy as np
    import trimesh

    from zcomp_cli.blender.intrinsics import render_box
    from zcomp_cli.blender.meshes import MAX_EXTENT_POINTS, load_mesh_info
    from zcomp_cli.camera import Camera
    from zcomp_cli.pose import Pose

    cam = Camera.from_fov(50.0, 320, 240)
    dense = trimesh.creation.icosphere(subdivisions=6)  # 40962 vertices, all on its hull
    dense.export(tmp_path / "dense.obj")
    chair = trimesh.util.concatenate([trimesh.creation.box([0.4, 0.05, 0.4]).apply_translation([0, 0.45, 0]),
                                      trimesh.creation.box([0.05, 0.45, 0.05]).apply_translation([0.17, 0.2, 0.17]),
                                      trimesh.creation.box([0.05, 0.45, 0.05]).apply_translation([-0.17, 0.2, -0.17])])
    chair.export(tmp_path / "chair.obj")
    rng = np.random.default_rng(0)
    for name, exact in (("dense.obj", False), ("chair.obj", True)):
        info = load_mesh_info(tmp_path / name)
        mesh = trimesh.load(tmp_path / name, force="mesh", process=False)
        V = np.asarray(mesh.vertices, np.float64)
        assert len(info.vertices) <= MAX_EXTENT_POINTS
        for _ in range(10):
            pose = Pose.from_dict({"position": [rng.uniform(-0.5, 0.5), -0.8, rng.uniform(-4, -2.5)],
                                   "rotation_deg": rng.uniform(-40, 40, 3).tolist(),
                                   "height": rng.uniform(0.3, 1.0)})
            M = pose.object_to_camera(info.bbox_min, info.bbox_max)
            few = render_box(info.vertices @ M[:3, :3].T + M[:3, 3], cam, pad=0)
            full = render_box(V @ M[:3, :3].T + M[:3, 3], cam, pad=0)
            if exact:
                assert few == full
            elif full is not None:
                assert few is None or (few[0] <= full[0] and few[1] >= full[1] and few[2] <= full[2]
                                       and few[3] >= full[3])


def test_estimate_on_a_3e38_image_prints_no_runtime_warning(tmp_path):
    """Raw RuntimeWarnings (overflow in a cast and a divide) from `estimate` on an image
    of 3e38."""
    import numpy as np
    import yaml

    from zcomp_cli.imageio import write_exr

    img = np.full((48, 64, 3), 3e38, np.float32)
    img[:10] = 0.5
    write_exr(tmp_path / "img.exr", img)
    doc = {"version": 1, "scenes": {"s": {"image": "img.exr", "fov_deg": 50, "depth": {
        "proxy": "ground_plane", "camera_height": 1.5, "pitch_deg": -20}}},
        "objects": {"c": {"image": "img.exr", "mask": "img.exr"}},
        "jobs": [{"scene": "s", "object": "c", "placement": {"pixel": [32, 40], "height": 0.2}}]}
    (tmp_path / "jobs.yaml").write_text(yaml.safe_dump(doc))
    r = _zcomp("estimate", tmp_path / "jobs.yaml", "--out", tmp_path / "est")
    assert r.returncode == 0, r.stderr
    assert "Warning" not in r.stderr, r.stderr


def test_no_loading_bar_from_transformers_under_q(tiny_dpt, tmp_path):
    """transformers' "Loading weights" bar showed under -q."""
    import shutil

    import yaml

    make_project(tmp_path)
    shutil.copytree(tiny_dpt, tmp_path / "dpt")
    doc = yaml.safe_load((tmp_path / "jobs.yaml").read_text())
    doc["scenes"]["room"]["depth"] = {"model": "dpt"}
    doc["jobs"] = doc["jobs"][1:]
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(doc))
    r = _zcomp("-q", "estimate", tmp_path / "m.yaml", "--out", tmp_path / "est")
    assert r.returncode == 0, r.stderr
    assert "Loading" not in r.stderr and "it/s" not in r.stderr and "%|" not in r.stderr, r.stderr


# ------------------------------------------------------------------ SIGTERM's summary
def test_sigterm_prints_what_is_on_disk(tmp_path):
    """SIGTERM during a batch printed only "Interrupted.", where the README promises a
    summary of what is on disk."""
    import signal

    from hostile_project import default_signals
    from test_hostile_input_round2 import _long_batch, _wait_for_reports

    m = _long_batch(tmp_path)
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "zcomp_cli", "-q", "composite", str(m), "--out", str(out)],
                         env=dict(os.environ, PYTHONPATH=str(SRC)), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, preexec_fn=default_signals)
    _wait_for_reports(out, 3, p)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=CHILD_BOUND_S)
    assert p.returncode == 143, err
    doc = json.loads((out / "summary.json").read_text())
    said = " ".join(err.split())
    assert f"{doc['done']} done, {doc['failed']} failed, {doc['pending']} pending" in said, err
    assert "summary.json" in said and "--resume" in said and said.count("Interrupted") == 1


# ------------------------------------------------------------------ the coffee photograph
def _coffee(tmp_path, depth: str | None) -> Path:
    import shutil

    import numpy as np

    from zcomp_cli.imageio import write_png

    root = tmp_path / "coffee"
    root.mkdir(parents=True)
    shutil.copy(SRC.parent / "docs/coffee/coffee.png", root / "coffee.png")
    img = np.zeros((16, 16, 3), np.float32) + np.float32([0.6, 0.2, 0.1])
    mask = np.zeros((16, 16), np.float32)
    mask[1:15, 4:12] = 1.0
    write_png(root / "card.png", img)
    write_png(root / "card_mask.png", mask, srgb_encode=False)
    scene = "{image: coffee.png, fov_deg: 50" + (f", depth: {depth}" if depth else "") + "}"
    (root / "jobs.yaml").write_text(
        f"version: 1\ndefaults: {{renderer: naive}}\nscenes:\n  table: {scene}\n"
        "objects:\n  card: {image: card.png, mask: card_mask.png}\n"
        "jobs:\n  - {scene: table, object: card, placement: {pixel: [480, 330], height: 0.14}}\n")
    return root / "jobs.yaml"


def test_a_photograph_without_maps_gets_a_suggestion_that_fits_it(tmp_path):
    """The refusal suggested {camera_height: 1.5, pitch_deg: -10} whatever the
    photograph: on the coffee photograph (a table top seen from above) it made a 0.14 m
    vase a speck. The suggestion now gives a ground plane per typical view, fitted to the
    photograph and the job's object; pasted, it makes the object about a fifth of the
    frame tall. The old line still runs, with a warning that the object is a speck."""
    import re

    from zcomp_cli.estimators.ground_suggest import TARGET_SHARE
    from zcomp_cli.imageio import read_alpha_or_grey

    r = CliRunner().invoke(cli, ["composite", str(_coffee(tmp_path, None)), "--out", str(tmp_path / "out")])
    text = " ".join(r.output.split())
    assert r.exit_code == 2 and "no depth" in text, r.output
    lines = re.findall(r"depth: (\{proxy: ground_plane, camera_height: [\d.e+-]+, pitch_deg: -?[\d.]+\}) for ([a-z ]+)",
                       text)
    assert [w for _, w in lines] == ["a room seen standing", "a table top or floor seen from above"], text
    for k, (line, _) in enumerate(lines):
        m = _coffee(tmp_path / f"s{k}", line)
        out = tmp_path / f"out{k}"
        assert run_composite(m, out, "--debug").exit_code == 0
        obj = read_alpha_or_grey(out / "000_table_card/debug/object_mask.exr") > 0.5
        rows = obj.any(1).nonzero()[0]
        assert abs((rows[-1] - rows[0] + 1) / (TARGET_SHARE * obj.shape[0]) - 1) < 0.35, (line, rows)
        notes = json.loads((out / "000_table_card/report.json").read_text())["notes"]
        assert not any("a speck" in n for n in notes)
    old = _coffee(tmp_path / "old", "{proxy: ground_plane, camera_height: 1.5, pitch_deg: -10}")
    assert run_composite(old, tmp_path / "out_old").exit_code == 0
    notes = json.loads((tmp_path / "out_old/000_table_card/report.json").read_text())["notes"]
    assert any("a speck" in n and "camera_height" in n for n in notes), notes


def test_a_huge_sun_direction_is_normalised_not_zeroed(project, tmp_path):
    """Found by the fuzzer: a sun `direction: [0, 0, 1.3e154]` with pitch_deg given was
    normalised through a sum of squares that overflowed (the direction became 0) and
    validation raised a ValueError."""
    import yaml

    doc = yaml.safe_load((project / "jobs.yaml").read_text())
    doc["scenes"]["room"]["light"] = {"type": "sun", "direction": [0, 1.2711610061536462e308, 1.2e308]}
    doc["scenes"]["room"]["pitch_deg"] = 0.0
    (project / "m.yaml").write_text(yaml.safe_dump(doc))
    r = run_composite(project / "m.yaml", tmp_path / "out")
    assert r.exit_code == 0, r.output
    doc["scenes"]["room"]["light"]["direction"] = [0, 0, 1.3407807929942597e154]  # straight back: below
    (project / "m.yaml").write_text(yaml.safe_dump(doc))
    r = run_composite(project / "m.yaml", tmp_path / "out2")
    assert r.exit_code == 2 and "below the horizon" in " ".join(r.output.split()), r.output
