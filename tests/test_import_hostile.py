"""``zcomp import`` against hostile and careless archives (issue 39, defects 6 and 7 and
the import's low ones): one bad case is that case's failure, named, and the others are
imported; nothing aborts the whole import with a traceback."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from click.testing import CliRunner

import lvsn_replica as replica
from zcomp_cli.cli import cli
from zcomp_cli.pipeline.manifest import load_manifest

CONTROL = "rendered_2024-10-20_19-07-58_control"


def run(*args):
    return CliRunner().invoke(cli, list(map(str, args)), catch_exceptions=False)


def _light_file(root: Path, case: str) -> Path:
    return root / case / f"{case}_light_path_dto.json"


def _frames(*frames) -> str:
    return json.dumps({"light_frames": [{"name": n, "blender_light_xyz_position_object_space": v}
                                        for n, v in frames]})


@pytest.fixture
def spot(tmp_path):
    data = tmp_path / "data"
    cases = replica.make_spotlight_archive(data, 4)
    return data / CONTROL, [c.name for c in cases]


def _as_case(parent: Path, old: str, new: str, *, copy: bool = False) -> None:
    """Case folder ``parent/old`` moved (or copied) to ``parent/new``, its files renamed
    as the archives name them (``<case>_bundle0001.exr``...)."""
    (shutil.copytree if copy else os.rename)(parent / old, parent / new)
    for f in (parent / new).iterdir():
        f.rename(parent / new / f.name.replace(old, new))


def _imported(out: Path) -> list[str]:
    return json.loads((out.parent / f"{out.stem}_data" / "import.json").read_text())["imported"]


def test_bad_light_files_fail_their_case_only(spot, tmp_path):
    root, names = spot
    _light_file(root, names[0]).write_text(_frames(("gt_dir", [int("1" + "0" * 400), 0, 1])))
    _light_file(root, names[1]).write_text("[" * 100_000 + "]" * 100_000)
    _light_file(root, names[2]).write_text(_frames(("gt_dir", [1e308, 0, 1])))
    out = tmp_path / "o" / "jobs.yaml"
    r = run("import", "spotlight", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 1, r.output
    assert f"failed {names[0]}" in r.output and "expected 3 finite numbers" in r.output
    assert f"failed {names[1]}" in r.output and "nested deeper than the parser allows" in r.output
    assert f"failed {names[2]}" in r.output and "overflows" in r.output
    assert "1 case imported (1 job), 3 failed" in r.output
    assert _imported(out) == [names[3]]
    load_manifest(out)


def test_a_40000_frame_light_file_reads_in_linear_time(tmp_path):
    from zcomp_cli.datasets.lights import read_light_frames

    p = tmp_path / "l.json"
    p.write_text(_frames(*((f"{i:05d}", [0.1, 0.2, 0.9]) for i in range(40_000))))
    assert len(read_light_frames(p)) == 40_000
    p.write_text(_frames(*((f"{i:05d}", [0.1, 0.2, 0.9]) for i in range(39_999)), ("00007", [0, 0, 1])))
    with pytest.raises(Exception, match=r"light_frames\[39999\]: the frame name '00007' repeats"):
        read_light_frames(p)


def test_names_the_manifest_refuses_are_renamed(tmp_path):
    """A case named ``7`` (a --jobs index) or ``summary.json`` (a file zcomp writes) is
    imported under a ``case_`` name, its own name kept in case.json."""
    root = tmp_path / "labo"
    cases = replica.make_zerocomp_archive(root, 1)
    g = root / "GT_emission_envmap"
    for nm in ("7", "summary.json"):
        _as_case(g, cases[0].name, nm, copy=True)
    out = tmp_path / "o" / "jobs.yaml"
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 0, r.output
    m = load_manifest(out)
    assert set(m.scenes) == {cases[0].name, "case_7", "case_summary.json"}
    info = json.loads((out.parent / "jobs_data" / "case_7" / "case.json").read_text())
    assert info["case"] == "7" and info["name"] == "case_7"


def test_frame_scenes_never_collide_with_other_cases(tmp_path):
    """--lights all names a frame's scene <case>_light<frame>: a case already named so
    keeps its name and the frame's scene takes another."""
    data = tmp_path / "data"
    cases = replica.make_spotlight_archive(data, 2)
    root = data / CONTROL
    a, b = cases[0].name, cases[1].name
    # case b renamed to what case a's first frame's scene would be called
    clash = f"{a}_light0000"
    _as_case(root, b, clash)
    _as_case(data / "WACV_bg_estimates", b, clash)
    # case a's second frame makes the scene name the clash case's gt_dir frame makes
    _light_file(root, a).write_text(_frames(("gt_dir", [0.3, -0.2, 0.9]), ("0000_lightgt_dir", [1, 0, 0])))
    out = tmp_path / "o" / "jobs.yaml"
    r = run("import", "spotlight", root, "--out", out, "--maps", "provided", "--lights", "all")
    assert r.exit_code == 0, r.output
    m = load_manifest(out)
    assert sorted(m.scenes) == [f"{a}_light0000_light0000", f"{a}_light0000_lightgt_dir",
                                f"{a}_light0000_lightgt_dir-2", f"{a}_lightgt_dir"]
    assert len({j.name for j in m.jobs}) == 4


def test_a_case_only_the_manifest_refuses_fails_alone(spot, tmp_path):
    """A 1x1 case reads as a bundle but no manifest takes it: it fails with the
    manifest's reason, before the final check, and the others are kept."""
    from PIL import Image

    from zcomp_cli.imageio import write_exr

    root, names = spot
    sc, b, bg, comp = replica.make_case(1)
    ys, xs = np.nonzero(b.mask > 0.9)
    y, x = ys[len(ys) // 2], xs[len(xs) // 2]
    ch = replica.bundle_channels(b, bg, comp, normals_frame="opengl")
    c = names[1]
    replica.write_bundle(root / c / f"{c}_bundle0001.exr", {k: v[y:y + 1, x:x + 1] for k, v in ch.items()})
    est = root.parent / "WACV_bg_estimates" / c
    for f in est.glob("*.png"):
        Image.fromarray(np.asarray(Image.open(f))[y:y + 1, x:x + 1]).save(f)
    write_exr(est / f"{c}_bg_depth.exr", np.full((1, 1, 3), 3.0, np.float32))
    out = tmp_path / "o" / "jobs.yaml"
    r = run("import", "spotlight", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 1, r.output
    assert f"failed {c}: the case's manifest entry does not validate" in r.output
    assert "1x1; a scene needs at least 2x2" in r.output
    assert _imported(out) == [n for n in names if n != c]
    assert not (out.parent / "jobs_data" / c).exists()
    load_manifest(out)


def test_the_manifest_size_limit_is_said_up_front_and_the_rest_listed(spot, tmp_path, monkeypatch):
    root, names = spot
    out0 = tmp_path / "one" / "jobs.yaml"
    assert run("import", "spotlight", root, "--out", out0, "--maps", "provided", "--limit", "1").exit_code == 0
    one = len(out0.read_bytes())
    monkeypatch.setenv("ZCOMP_MAX_MANIFEST_BYTES", str(int(one * 1.9)))  # room for one case, not two
    out = tmp_path / "o" / "jobs.yaml"
    r = run("import", "spotlight", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 1, r.output
    assert "Warning: 4 cases make a manifest of about" in r.output
    assert r.output.index("Warning") < r.output.index("failed")  # said before the end
    kept = _imported(out)
    assert 1 <= len(kept) < len(names) and kept == names[:len(kept)]
    assert r.output.count("not imported: the manifest would pass its size limit") == len(names) - len(kept)
    load_manifest(out)  # the manifest written loads under the same limit


def test_non_utf8_and_newline_names(tmp_path):
    """A Latin-1 case folder and a newline in the archive's path: the case is imported
    under a safe name, the manifest stays one valid YAML document."""
    root = tmp_path / "ar\nchive" / "labo"
    cases = replica.make_zerocomp_archive(root, 1)
    g = root / "GT_emission_envmap"
    latin = os.fsdecode(b"caf\xe9")
    _as_case(g, cases[0].name, latin, copy=True)
    out = tmp_path / "o" / "jobs.yaml"
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 1, r.output
    # OpenImageIO opens UTF-8 paths only: that case fails, named, and the other is kept
    assert "failed caf\\udce9" in r.output and "not valid UTF-8" in r.output
    m = load_manifest(out)
    assert set(m.scenes) == {cases[0].name}
    head = out.read_text().splitlines()[0]
    assert head.startswith("# zcomp import") and "ar\\nchive" in head
    rep = json.loads((out.parent / "jobs_data" / "import.json").read_text())
    assert list(rep["failed"]) == [latin]


def test_non_utf8_out_is_a_usage_error(tmp_path):
    root = tmp_path / "labo"
    replica.make_zerocomp_archive(root, 1)
    r = run("import", "zerocomp", root, "--out", tmp_path / os.fsdecode(b"j\xe9.yaml"), "--maps", "provided")
    assert r.exit_code == 2 and "not valid UTF-8" in r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["labo"]


def test_a_file_where_a_folder_is_expected(tmp_path):
    root = tmp_path / "labo"
    replica.make_zerocomp_archive(root, 1)
    (tmp_path / "f").write_text("x")
    r = run("import", "zerocomp", root, "--out", tmp_path / "f" / "jobs.yaml", "--maps", "provided")
    assert r.exit_code == 2 and "is a file, not a folder" in r.output
    # a file where the data folder goes: refused, then replaced with --overwrite, no .old left
    out = tmp_path / "o" / "jobs.yaml"
    out.parent.mkdir()
    (out.parent / "jobs_data").write_text("x")
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 2 and "jobs_data" in r.output
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided", "--overwrite")
    assert r.exit_code == 0, r.output
    assert (out.parent / "jobs_data").is_dir()
    assert sorted(p.name for p in out.parent.iterdir()) == ["jobs.yaml", "jobs_data"]


def test_two_imports_into_one_manifest(tmp_path):
    """While one import holds the manifest, a second one is refused with who holds it
    (they shared the partial folder: both failed, one with a traceback)."""
    from zcomp_cli.pipeline.outguard import _FileLock

    root = tmp_path / "labo"
    replica.make_zerocomp_archive(root, 1)
    out = tmp_path / "o" / "jobs.yaml"
    out.parent.mkdir()
    other = _FileLock(out.parent / ".jobs.yaml.import.lock", {"pid": 4242, "what": "zcomp import"})
    assert other.try_acquire() is None
    try:
        r = run("import", "zerocomp", root, "--out", out, "--maps", "provided")
        assert r.exit_code == 2 and "another zcomp import (pid 4242) is writing" in r.output
        assert not out.exists()
    finally:
        other.release()
    r = run("import", "zerocomp", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in out.parent.iterdir()) == ["jobs.yaml", "jobs_data"]  # lock file removed


def test_manifest_written_is_the_same_from_another_path(tmp_path):
    """Re-importing the same archive from another path changes no job (the absolute
    source path was hashed: every job read as changed)."""
    from zcomp_cli.pipeline.fingerprint import job_fingerprint

    def job_fingerprints(m):
        return [job_fingerprint(m, j, m.defaults.renderer, m.defaults.samples) for j in m.jobs]

    root = tmp_path / "a" / "labo"
    replica.make_zerocomp_archive(root, 2)
    out = tmp_path / "o" / "jobs.yaml"
    assert run("import", "zerocomp", root, "--out", out, "--maps", "provided").exit_code == 0
    before = job_fingerprints(load_manifest(out))
    moved = tmp_path / "b" / "labo"
    moved.parent.mkdir()
    root.rename(moved)
    assert run("import", "zerocomp", moved, "--out", out, "--maps", "provided", "--overwrite").exit_code == 0
    assert job_fingerprints(load_manifest(out)) == before
    assert yaml.safe_load(out.read_text())  # still one document


def test_a_fifo_is_named_as_a_fifo_and_never_opened(spot, tmp_path):
    """A FIFO in place of a map or a light file: that case fails saying so (it was
    reported as not found; opening it would hang the import)."""
    root, names = spot
    light = _light_file(root, names[0])
    light.unlink()
    os.mkfifo(light)
    normal = root.parent / "WACV_bg_estimates" / names[1] / f"{names[1]}_bg_normal.png"
    normal.unlink()
    os.mkfifo(normal)
    out = tmp_path / "o" / "jobs.yaml"
    r = run("import", "spotlight", root, "--out", out, "--maps", "provided")
    assert r.exit_code == 1, r.output
    assert f"failed {names[0]}: '{light}' is a FIFO (named pipe), not a regular file" in r.output
    assert f"failed {names[1]}: '{normal}' is a FIFO (named pipe), not a regular file" in r.output
    assert _imported(out) == names[2:]


def test_one_broken_case_json_does_not_switch_the_protocol(tmp_path):
    """eval picks the paper's protocol for imported cases; one unreadable case.json
    switched every case to zcomp's, silently. Now the others decide and it is named."""
    root = tmp_path / "labo"
    cases = replica.make_zerocomp_archive(root, 2)
    out = tmp_path / "o" / "jobs.yaml"
    assert run("import", "zerocomp", root, "--out", out, "--maps", "provided").exit_code == 0
    res = tmp_path / "naive"
    assert run("composite", out, "--out", res, "--renderer", "naive").exit_code == 0
    broken = out.parent / "jobs_data" / cases[1].name / "case.json"
    broken.write_text("{not json")
    r = run("eval", res, "--metrics", "psnr", "--out", tmp_path / "ev")
    assert r.exit_code == 0, r.output
    proto = json.loads((tmp_path / "ev.json").read_text())["protocol"]
    assert proto["name"] == "paper" and proto["dataset"] == "zerocomp-labo"
    assert f"1 case.json file could not be read (the protocol follows the others): {broken}" in r.output
    assert proto["warnings"]
    # a mix of imported cases and plain references is said, not silent
    broken.unlink()
    r = run("eval", res, "--metrics", "psnr", "--out", tmp_path / "ev2")
    assert r.exit_code == 0 and "the references mix 1 zerocomp-labo case, 1 reference not from `zcomp import`" in r.output
    assert json.loads((tmp_path / "ev2.json").read_text())["protocol"]["name"] == "zcomp"
