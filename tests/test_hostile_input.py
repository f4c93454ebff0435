"""Hostile and broken input (issue 12): each attack that once broke zcomp, kept as a test.

Runs on the mesh-free project of ``hostile_project`` (no Blender), with the naive
renderer: every test here takes well under a second or two.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

from hostile_project import base_manifest, make_project, run_composite, write_manifest
from zcomp_cli.cli import cli
from zcomp_cli.errors import ManifestError
from zcomp_cli.imageio import verify_image, write_exr, write_json_atomic, write_png
from zcomp_cli.pipeline.manifest import load_manifest
from zcomp_cli.yamlloc import load_yaml

SRC = Path(__file__).resolve().parents[1] / "src"


def _strict_load(path):
    """json.load that refuses NaN / Infinity (what a strict parser, e.g. a browser, does)."""
    def bad(c):
        raise ValueError(f"non-standard JSON constant {c}")
    return json.loads(Path(path).read_text(), parse_constant=bad)


@pytest.fixture
def project(tmp_path):
    make_project(tmp_path)
    return tmp_path


_write = write_manifest
_composite = run_composite


def _problems(path) -> list[str]:
    with pytest.raises(ManifestError) as ei:
        load_manifest(path)
    assert ei.value.exit_code == 2
    return ei.value.problems


# ------------------------------------------------------------------ YAML: bombs and size
BOMB = "".join(
    f"{a}: &{a} [{', '.join([f'*{p}'] * 9 if p else ['lol'] * 9)}]\n"
    for a, p in zip("abcdefghi", ["", *"abcdefgh"])
) + "version: *i\n"


def test_alias_bomb_refused_fast(tmp_path):
    p = tmp_path / "bomb.yaml"
    p.write_text(BOMB)
    assert p.stat().st_size < 1500
    with pytest.raises(ManifestError, match="alias bomb") as ei:
        load_yaml(p)
    assert len(str(ei.value)) < 400


def test_recursive_alias_refused(tmp_path):
    p = tmp_path / "r.yaml"
    p.write_text("a: &a [1, *a]\n")
    with pytest.raises(ManifestError, match="recursive alias"):
        load_yaml(p)


def test_small_aliases_still_work(tmp_path):
    p = tmp_path / "ok.yaml"
    p.write_text("p: &p {position: [0, -1, -3]}\njobs: [{pose: *p}, {pose: *p}]\n")
    assert load_yaml(p)["jobs"][1]["pose"]["position"] == [0, -1, -3]


def test_manifest_size_limit(project, monkeypatch):
    doc = base_manifest()
    doc["jobs"] = doc["jobs"] * 1  # a valid manifest, padded with a long comment
    p = _write(project, yaml.safe_dump(doc) + "#" + "x" * 5000 + "\n")
    monkeypatch.setenv("ZCOMP_MAX_MANIFEST_BYTES", "4000")
    with pytest.raises(ManifestError, match="ZCOMP_MAX_MANIFEST_BYTES"):
        load_yaml(p)
    monkeypatch.setenv("ZCOMP_MAX_MANIFEST_BYTES", "100000")
    load_manifest(p)


def test_long_values_are_shortened_in_messages(project):
    doc = base_manifest()
    doc["jobs"][0]["scene"] = "r" * 100_000
    doc["jobs"][1]["placement"]["pixel"] = list(range(50_000))
    msg = "\n".join(_problems(_write(project, doc)))
    assert "unknown scene" in msg and "placement.pixel" in msg
    assert len(msg) < 1000


# ------------------------------------------------------------------ YAML types
def test_exponent_floats_are_numbers(tmp_path):
    p = tmp_path / "f.yaml"
    p.write_text("a: 1e9\nb: -2E-3\nc: 12\nd: 1e9x\n")
    assert load_yaml(p) == {"a": 1e9, "b": -2e-3, "c": 12, "d": "1e9x"}


@pytest.mark.parametrize("edit, field", [
    (lambda d: d["jobs"][1]["placement"].update(height=True), "jobs[1].placement.height"),
    (lambda d: d["jobs"][0]["pose"].update(height=True), "jobs[0].pose.height"),
    (lambda d: d["jobs"][0]["pose"].update(position=["0", "-1", "-3"]), "jobs[0].pose.position"),
    (lambda d: d["jobs"][0]["pose"].update(position=[True, 0, -3]), "jobs[0].pose.position"),
    (lambda d: d["jobs"][0]["pose"].update(scale="2"), "jobs[0].pose.scale"),
    (lambda d: d["jobs"][1]["placement"].update(pixel=["16", 20]), "jobs[1].placement.pixel"),
])
def test_booleans_and_strings_are_not_numbers(project, edit, field):
    doc = base_manifest()
    edit(doc)
    probs = _problems(_write(project, doc))
    assert len(probs) == 1 and field in probs[0], probs


def test_no_doubled_prefix_or_python_type_names(project):
    doc = base_manifest()
    doc["jobs"][0]["pose"] = {"position": [1, 2], "quaternion": [0, 0, 0, 0]}
    doc["jobs"][1] = {"scene": "room", "object": "ball", "pose": [1, 2, 3]}
    msg = "\n".join(_problems(_write(project, doc)))
    assert "jobs[0].pose.position" in msg and "jobs[0].pose.quaternion" in msg
    assert "jobs[0].pose: jobs[0]" not in msg and "pose: jobs" not in msg
    assert "LocList" not in msg and "LocDict" not in msg and "a list" in msg


def test_single_problem_names_the_file_once(project):
    doc = base_manifest()
    doc["jobs"][0]["seed"] = -5
    r = _composite(_write(project, doc), project / "out")
    assert r.exit_code == 2
    assert r.output.count("m.yaml") == 1 and "jobs[0].seed" in r.output


# ------------------------------------------------------------------ types -> exit 2
@pytest.mark.parametrize("edit, needle", [
    (lambda d: d["jobs"][0].update(scene=["room"]), "jobs[0].scene"),
    (lambda d: d["jobs"][0].update(object={"a": 1}), "jobs[0].object"),
    (lambda d: d["jobs"][0].update(seed=-5), "jobs[0].seed"),
    (lambda d: d["defaults"].update(seed=2**40), "defaults.seed"),
    (lambda d: d["defaults"].update(samples=True), "defaults.samples"),
    (lambda d: d["defaults"].update(renderer={"name": "physical", "march_steps": "lots"}), "march_steps"),
    (lambda d: d["scenes"]["room"].update(depth=[1, 2]), "scenes.room.depth"),
    (lambda d: d["scenes"]["room"].update(K=[[1, 0, 0], [0, 1, 0], ["a", 0, 1]]), "scenes.room.K"),
])
def test_wrong_types_are_clean_usage_errors(project, edit, needle):
    doc = base_manifest()
    edit(doc)
    r = _composite(_write(project, doc), project / "out")
    assert r.exit_code == 2, r.output
    assert needle in r.output and "Traceback" not in r.output
    assert not (project / "out" / "000_room_ball").exists()


# ------------------------------------------------------------------ names and paths
@pytest.mark.parametrize("name", ["..", ".", ".hidden", "/abs", "a/b", "a\\b", "summary.json", "x" * 300, "", 7])
def test_output_names_stay_inside_out(project, name):
    doc = base_manifest()
    doc["jobs"][0]["output"] = name
    probs = _problems(_write(project, doc))
    assert len(probs) == 1 and "jobs[0].output" in probs[0], probs


@pytest.mark.parametrize("name", ["..", ".", "a/b", "x" * 300])
def test_scene_and_object_names_are_folder_safe(project, name):
    doc = base_manifest()
    doc["scenes"][name] = doc["scenes"].pop("room")
    doc["objects"][name] = doc["objects"].pop("ball")
    for j in doc["jobs"]:
        j["scene"] = name
    doc["jobs"][0]["object"] = name
    msg = "\n".join(_problems(_write(project, doc)))
    assert "scene name" in msg and "object name" in msg


def test_dotdot_output_writes_nothing_outside(project):
    doc = base_manifest()
    doc["jobs"][0]["output"] = ".."
    out = project / "sub" / "out"
    before = sorted(p for p in project.rglob("*"))
    r = _composite(_write(project, doc), out)
    assert r.exit_code == 2
    after = sorted(p for p in project.rglob("*"))
    assert [p for p in after if p not in before] == [project / "m.yaml"] or after == before


def test_estimate_scene_named_dotdot_refused(project):
    doc = base_manifest()
    doc["scenes"][".."] = doc["scenes"].pop("room")
    for j in doc["jobs"]:
        j["scene"] = ".."
    depth = (project / "scenes/depth.exr").read_bytes()
    r = CliRunner().invoke(cli, ["-q", "estimate", str(_write(project, doc)), "--out", str(project / "est" / "x")])
    assert r.exit_code == 2 and "scenes.." in r.output
    assert (project / "scenes/depth.exr").read_bytes() == depth


@pytest.mark.parametrize("out", ["/proc/zcomp-x", "/proc/zcomp-x/y"])
def test_unwritable_out_is_a_usage_error(project, out):
    r = _composite(project / "jobs.yaml", out)
    assert r.exit_code == 2 and "--out" in r.output


def test_out_that_is_a_file(project):
    r = _composite(project / "jobs.yaml", project / "jobs.yaml")
    assert r.exit_code == 2


# ------------------------------------------------------------------ pixel budget
def test_resolution_over_budget(project):
    doc = base_manifest()
    doc["defaults"]["resolution"] = [40960, 30720]
    probs = _problems(_write(project, doc))
    assert any("defaults.resolution" in p and "ZCOMP_MAX_PIXELS" in p and "40,000,000" in p for p in probs)


def test_native_scene_over_budget(project, monkeypatch):
    monkeypatch.setenv("ZCOMP_MAX_PIXELS", "500")  # the 32x24 scene is 768 pixels
    probs = _problems(project / "jobs.yaml")
    assert any("scenes.room.image" in p and "pixel budget of 500" in p for p in probs), probs
    monkeypatch.setenv("ZCOMP_MAX_PIXELS", "800")
    load_manifest(project / "jobs.yaml")


def test_reader_refuses_over_budget_before_allocating(project, monkeypatch):
    from zcomp_cli.errors import InputError
    from zcomp_cli.imageio import read_image

    monkeypatch.setenv("ZCOMP_MAX_PIXELS", "100")
    with pytest.raises(InputError, match="pixel budget"):
        read_image(project / "scenes/room.png")


def test_render_intrinsics_resolution_over_budget(tmp_path):
    mesh = tmp_path / "m.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    r = CliRunner().invoke(cli, ["render-intrinsics", "--mesh", str(mesh), "--position", "0", "0", "-3",
                                 "--resolution", "16000", "12000", "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "--resolution" in r.output and "ZCOMP_MAX_PIXELS" in r.output


def test_bad_budget_setting(project, monkeypatch):
    monkeypatch.setenv("ZCOMP_MAX_PIXELS", "lots")
    r = _composite(project / "jobs.yaml", project / "out")
    assert r.exit_code == 2 and "ZCOMP_MAX_PIXELS" in r.output


# ------------------------------------------------------------------ broken files
@pytest.mark.parametrize("name, writer", [
    ("scenes/room.png", lambda p: write_png(p, np.random.rand(24, 32, 3).astype(np.float32))),
    ("scenes/depth.exr", lambda p: write_exr(p, np.random.rand(24, 32).astype(np.float32) + 1)),
])
def test_truncated_files_fail_validation_with_a_reason(project, name, writer):
    p = project / name
    writer(p)
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="truncated"):
        verify_image(p)
    probs = _problems(project / "jobs.yaml")
    field = "scenes.room.image" if name.endswith(".png") else "scenes.room.depth"
    assert any(field in x and "truncated" in x for x in probs), probs


def test_non_square_K_blamed_on_camera(project):
    doc = base_manifest()
    mesh = project / "objects/tri.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    doc["objects"]["tri"] = {"mesh": "objects/tri.obj"}
    doc["scenes"]["room"].pop("fov_deg")
    doc["scenes"]["room"]["K"] = [[30, 0, 16], [0, 40, 12], [0, 0, 1]]
    doc["jobs"].append({"scene": "room", "object": "tri", "pose": {"position": [0, -1, -3]}})
    probs = _problems(_write(project, doc))
    assert len(probs) == 1 and "scenes.room.K" in probs[0] and "non-square" in probs[0], probs


# ------------------------------------------------------------------ outputs
def test_write_errors_never_install_a_file(tmp_path):
    """A full disk (here: a file-size limit) makes the writers raise; nothing is left."""
    code = f"""
import resource, signal, sys
sys.path.insert(0, {str(SRC)!r})
import numpy as np
from zcomp_cli.errors import OutputError
from zcomp_cli.imageio import write_exr, write_png, write_json_atomic
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
img = np.random.default_rng(0).random((256, 256, 3)).astype(np.float32)
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
failed = []
for name, fn in (("a.png", write_png), ("a.exr", write_exr),
                 ("a.json", lambda p, _: write_json_atomic(p, {{"x": "y" * 10000}}))):
    try:
        fn({str(tmp_path)!r} + "/" + name, img)
    except OutputError as exc:
        failed.append(name)
print(",".join(failed))
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "a.png,a.exr,a.json"
    assert list(tmp_path.iterdir()) == [], "a partial or temporary file was left"


def test_json_is_strict(tmp_path):
    write_json_atomic(tmp_path / "a.json", {"x": float("nan"), "y": [1.0, np.float32("inf")],
                                            "z": np.array([np.nan])})
    d = _strict_load(tmp_path / "a.json")
    assert d["x"] is None and d["y"] == [1.0, None] and d["z"] == [None]
    assert "x" in d["json_notes"][0] and "y[1]" in d["json_notes"][0]


def test_degenerate_maps_give_strict_reports(project):
    """Black background, zero albedo, zero normals: every JSON written parses strictly."""
    write_png(project / "scenes/room.png", np.zeros((24, 32, 3), np.float32))
    write_exr(project / "scenes/albedo.exr", np.zeros((24, 32, 3), np.float32))
    write_exr(project / "scenes/normals.exr", np.zeros((24, 32, 3), np.float32))
    out = project / "out"
    for renderer in ("naive", "physical"):
        r = _composite(project / "jobs.yaml", out / renderer, "--renderer", renderer)
        assert r.exit_code in (0, 1), r.output
    files = list(out.rglob("*.json"))
    assert len(files) >= 2
    for f in files:
        _strict_load(f)


def test_zero_albedo_warns(project):
    write_exr(project / "scenes/albedo.exr", np.zeros((24, 32, 3), np.float32))
    out = project / "out"
    r = _composite(project / "jobs.yaml", out)
    assert r.exit_code == 0, r.output
    rep = _strict_load(out / "000_room_ball" / "report.json")
    assert any("albedo is ~0" in n for n in rep["notes"])


# ------------------------------------------------------------------ tiny scenes
def test_one_pixel_scene_refused_clearly(tmp_path):
    make_project(tmp_path, width=1, height=1)
    probs = _problems(tmp_path / "jobs.yaml")
    assert any("scenes.room.image" in p and "at least 2x2" in p for p in probs)


def test_four_by_three_scene_runs(tmp_path):
    make_project(tmp_path, width=4, height=3)
    r = _composite(tmp_path / "jobs.yaml", tmp_path / "out", "--renderer", "physical")
    assert r.exit_code in (0, 1) and "Traceback" not in r.output
    assert (tmp_path / "out" / "000_room_ball" / "composite.png").is_file(), r.output


# ------------------------------------------------------------------ placement frame
def test_placement_pixel_is_native_scaled_to_working_size(project):
    doc = base_manifest()
    doc["defaults"]["resolution"] = [16, 12]
    doc["jobs"][1]["placement"]["pixel"] = [30, 22]  # inside 32x24, outside 16x12
    m = load_manifest(_write(project, doc))
    pl = m.jobs[1].placement
    assert pl.pixel_native == (30.0, 22.0) and pl.pixel == (15.0, 11.0)
    r = _composite(project / "m.yaml", project / "out")
    assert r.exit_code in (0, 1) and "outside the 16x12" not in r.output
    doc["jobs"][1]["placement"]["pixel"] = [33, 5]
    assert any("outside the 32x24" in p for p in _problems(_write(project, doc)))


# ------------------------------------------------------------------ interrupts
def test_ctrl_c_exits_130(project, monkeypatch):
    import zcomp_cli.pipeline.manifest as manifest_mod
    from zcomp_cli.cli import main

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(manifest_mod, "load_manifest", interrupted)
    r = CliRunner().invoke(cli, ["composite", str(project / "jobs.yaml"), "--out", str(project / "o")])
    assert r.exit_code == 130
    with pytest.raises(SystemExit) as ei:
        main(["composite", str(project / "jobs.yaml"), "--out", str(project / "o")])
    assert ei.value.code == 130


def test_sigint_to_a_real_process_exits_130(project):
    import signal
    import time

    env = dict(os.environ, PYTHONPATH=str(SRC))
    code = ("import time, zcomp_cli.pipeline.manifest as m\n"
            "def slow(*a, **k):\n    print('ready', flush=True); time.sleep(30)\n"
            "m.load_manifest = slow\n"
            "from zcomp_cli.cli import main\n"
            f"main(['composite', {str(project / 'jobs.yaml')!r}, '--out', {str(project / 'o')!r}])\n")
    from hostile_project import default_signals

    p = subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, preexec_fn=default_signals)
    assert p.stdout.readline().strip() == "ready"
    time.sleep(0.1)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 130, err
    assert "Traceback" not in err


# ------------------------------------------------------------------ eval
def _pairs(root: Path, size, names=("a", "b")):
    rng = np.random.default_rng(0)
    for d in ("p", "r"):
        (root / d).mkdir(parents=True, exist_ok=True)
        for n in names:
            write_png(root / d / f"{n}.png", rng.random((*size, 3)).astype(np.float32))


def test_eval_all_metrics_on_one_pixel_images(tmp_path):
    _pairs(tmp_path, (1, 1))
    r = CliRunner().invoke(cli, ["eval", str(tmp_path / "p"), str(tmp_path / "r"), "--metrics", "all"])
    assert r.exit_code == 0, r.output
    d = _strict_load(tmp_path / "p" / "eval.json")
    assert "ssim" in d["unavailable"] and "7x7" in d["unavailable"]["ssim"]
    assert math.isfinite(d["mean"]["psnr"]) and d["images"][0]["ssim"] is None


def test_eval_scores_jobs_with_references_and_lists_the_rest(project):
    doc = base_manifest()
    write_png(project / "ref.png", np.full((24, 32, 3), 0.3, np.float32))
    doc["jobs"][0]["reference"] = "ref.png"
    out = project / "out"
    assert _composite(_write(project, doc), out).exit_code == 0
    r = CliRunner().invoke(cli, ["eval", str(out), "--metrics", "psnr,ssim"])
    assert r.exit_code == 0, r.output
    d = _strict_load(out / "eval.json")
    assert [i["name"] for i in d["images"]] == ["000_room_ball"]
    assert list(d["unscored"]) == ["001_room_card"] and "001_room_card" in r.output
