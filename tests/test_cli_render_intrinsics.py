"""``zcomp render-intrinsics``: manifest validation, usage errors, exit codes, and one
small Blender batch with good and bad items."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh

from zcomp_cli.bundle import ObjectBundle
from zcomp_cli.cli import main
from zcomp_cli.errors import ManifestError
from zcomp_cli.pipeline.objects_manifest import load_objects_manifest as load_manifest


def _run(argv, capsys):
    with pytest.raises(SystemExit) as ei:
        main(argv)
        raise SystemExit(0)
    cap = capsys.readouterr()
    return ei.value.code, cap.out, cap.err


@pytest.fixture()
def scene_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("ZCOMP_CACHE_DIR", str(tmp_path / "cache"))
    trimesh.creation.box(extents=(1, 1, 1)).export(tmp_path / "cube.glb")
    (tmp_path / "broken.stl").write_bytes(b"solid x\nfacet nonsense\n")
    (tmp_path / "cube.fbx").write_text("not supported")
    return tmp_path


def _yaml(folder: Path, text: str) -> Path:
    p = folder / "objects.yaml"
    p.write_text(textwrap.dedent(text))
    return p


def test_manifest_lists_every_problem_with_its_location(scene_dir, capsys):
    p = _yaml(scene_dir, """
        objects:
          cube: cube.glb
          bad: {mesh: cube.glb, colour: red}
        cameras:
          main: {fov_deg: 50}
          k: {K: [1, 2, 3], resolution: [32, 32]}
        renders:
          - {object: cube, camera: main, pose: {position: [0, 0, -3]}}
          - {object: chair, camera: nope, pose: {position: [0, 0, -3], spin: 3}}
          - {object: cube, camera: main, pose: {position: [0, 0, -3]}, name: a}
          - {object: cube, camera: main, pose: {rotation_deg: [0, 0, 0]}, name: a}
        extra: 1
        """)
    with pytest.raises(ManifestError) as ei:
        load_manifest(p)
    probs = "\n".join(ei.value.problems)
    for where in ("extra: unknown key", "objects.bad.colour", "cameras.main.resolution", "cameras.k.K",
                  "renders[1].object: unknown object 'chair'", "renders[1].camera: unknown camera 'nope'",
                  "renders[1].pose.spin", "renders[3].pose.position: required",
                  "renders[3].name: 'a' already used by renders[2]"):
        assert where in probs, where
    # each problem carries its file and line, like jobs.yaml's
    assert "objects.yaml:10: renders[1].camera" in probs
    code, out, err = _run(["render-intrinsics", str(p), "--out", str(scene_dir / "out")], capsys)
    assert code == 2 and "renders[1].camera" in err
    assert not (scene_dir / "out").exists()  # nothing rendered


def test_manifest_value_errors_become_item_errors(scene_dir):
    p = _yaml(scene_dir, """
        objects: {cube: cube.glb}
        cameras:
          zero: {fov_deg: 50, resolution: [0, 32]}
          wide: {fov_deg: 200, resolution: [32, 32]}
          ok: {K: [40, 40, 16, 16], resolution: [32, 32]}
        renders:
          - {object: cube, camera: zero, pose: {position: [0, 0, -3]}}
          - {object: cube, camera: wide, pose: {position: [0, 0, -3]}}
          - {object: cube, camera: ok, pose: {position: [0, 0, -3]}, name: fine}
        """)
    jobs = load_manifest(p)
    assert [j.name for j in jobs] == ["cube_000", "cube_001", "fine"]
    assert "renders[0]" in jobs[0].error and "0x32" in jobs[0].error
    assert "renders[1]" in jobs[1].error and "fov" in jobs[1].error
    assert jobs[2].error is None and jobs[2].mesh == scene_dir / "cube.glb"
    np.testing.assert_allclose(jobs[2].camera.K, [[40, 0, 16], [0, 40, 16], [0, 0, 1]])


@pytest.mark.parametrize("argv,needle", [
    ([], "either"),
    (["x.yaml", "--mesh", "m.glb"], "either"),
    (["--mesh", "m.glb"], "--position"),
    (["x.yaml", "--position", "0", "0", "-1"], "only apply with --mesh"),
    (["--mesh", "m.glb", "--position", "0", "0", "-1", "--rotation-deg", "0", "0", "0",
      "--quaternion", "1", "0", "0", "0"], "not both"),
    (["--mesh", "m.glb", "--position", "0", "0", "-1", "--scale", "-2"], "scale"),
])
def test_usage_errors_exit_2(argv, needle, tmp_path, capsys):
    code, _, err = _run(["render-intrinsics", *argv, "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and needle in err


def test_existing_output_needs_overwrite(scene_dir, capsys):
    out = scene_dir / "out"
    (out / "cube").mkdir(parents=True)
    (out / "cube" / "meta.json").write_text("{}")
    code, _, err = _run(["render-intrinsics", "--mesh", str(scene_dir / "cube.glb"), "--position", "0", "0", "-3",
                         "--out", str(out)], capsys)
    assert code == 2 and "--overwrite" in err


@pytest.mark.blender
@pytest.mark.slow
def test_batch_with_bad_items_and_cache(scene_dir, capsys, monkeypatch):
    p = _yaml(scene_dir, """
        objects:
          cube: cube.glb
          missing: nowhere/chair.glb
          broken: broken.stl
          fbx: cube.fbx
        cameras:
          main: {fov_deg: 50, resolution: [32, 24]}
          zero: {fov_deg: 50, resolution: [32, 0]}
        renders:
          - {object: cube, camera: main, pose: {position: [0, -0.5, -3], rotation_deg: [0, 20, 0]}, name: good}
          - {object: missing, camera: main, pose: {position: [0, -0.5, -3]}, name: no_file}
          - {object: broken, camera: main, pose: {position: [0, -0.5, -3]}, name: corrupt}
          - {object: fbx, camera: main, pose: {position: [0, -0.5, -3]}, name: unknown_format}
          - {object: cube, camera: main, pose: {position: [0, -0.5, 3]}, name: behind}
          - {object: cube, camera: zero, pose: {position: [0, -0.5, -3]}, name: zero_size}
          - {object: cube, camera: main, pose: {position: [0.5, -0.5, -4], height: 0.5}, name: good2}
        """)
    out = scene_dir / "out"
    code, stdout, err = _run(["render-intrinsics", str(p), "--out", str(out), "--samples", "4"], capsys)
    assert code == 1
    assert "2 done (0 from cache), 5 failed" in stdout
    for name, why in (("no_file", "not found"), ("corrupt", "broken.stl"), ("unknown_format", "unknown mesh format"),
                      ("behind", "behind the camera"), ("zero_size", "resolution must be positive")):
        line = next((ln for ln in err.splitlines() if ln.startswith(f"failed {name}:")), "")
        assert why in line, (name, err)
    b = ObjectBundle.load(out / "good")
    assert b.depth.shape == (24, 32) and (b.depth > 0).any()
    assert ObjectBundle.load(out / "good2").meta["object_height_m"] == pytest.approx(0.5)
    assert not (out / "no_file").exists()

    # again with --overwrite: the good items come from the cache, Blender never starts
    def no_blender(*a, **k):
        raise AssertionError("Blender must not start")

    monkeypatch.setattr("zcomp_cli.blender.runner.run_blender_batch", no_blender)
    code, stdout, _ = _run(["render-intrinsics", str(p), "--out", str(out), "--samples", "4", "--overwrite"], capsys)
    assert code == 1 and "2 done (2 from cache)" in stdout


@pytest.mark.blender
@pytest.mark.slow
def test_single_object_flags(scene_dir, capsys):
    out = scene_dir / "single"
    code, stdout, err = _run(["render-intrinsics", "--mesh", str(scene_dir / "cube.glb"),
                              "--position", "0", "-0.5", "-3", "--quaternion", "1", "0", "0", "0",
                              "--K", "30,30,14,12", "--resolution", "32", "24", "--out", str(out),
                              "--samples", "2", "--no-cache"], capsys)
    assert code == 0, err
    b = ObjectBundle.load(out / "cube")
    np.testing.assert_allclose(b.camera.K, [[30, 0, 14], [0, 30, 12], [0, 0, 1]])
    # front face at z = -2.5 through the principal point (14, 12): pixel (13.5..14.5)
    assert b.depth[12, 14] == pytest.approx(2.5, abs=1e-3)
    assert not (scene_dir / "cache").exists()  # --no-cache leaves the cache alone
