"""One cache for every command: its root, its folders, and sharing between commands."""

import pytest

from zcomp_cli.cache import KINDS, cache_dir, cache_root


def test_root_from_env_then_home(monkeypatch, tmp_path):
    monkeypatch.setenv("ZCOMP_CACHE_DIR", str(tmp_path / "zc"))
    assert cache_root() == tmp_path / "zc"
    assert cache_dir("intrinsics") == tmp_path / "zc" / "intrinsics"
    assert cache_dir("estimates") == tmp_path / "zc" / "estimates"
    monkeypatch.delenv("ZCOMP_CACHE_DIR")
    assert cache_root().parts[-2:] == (".cache", "zcomp")


def test_override_wins_over_env(monkeypatch, tmp_path):
    monkeypatch.setenv("ZCOMP_CACHE_DIR", str(tmp_path / "env"))
    assert cache_dir("estimates", tmp_path / "flag") == tmp_path / "flag" / "estimates"


def test_unknown_kind_is_refused():
    assert set(KINDS) == {"intrinsics", "estimates", "lights", "lpips"}
    with pytest.raises(ValueError, match="unknown cache kind"):
        cache_dir("bogus")


def test_one_samples_default_for_both_commands():
    """render-intrinsics and composite must render with the same settings, or they
    never share a cache entry."""
    from zcomp_cli.blender import DEFAULT_SAMPLES
    from zcomp_cli.pipeline.manifest import Defaults

    assert Defaults().samples == DEFAULT_SAMPLES


def test_composite_caches_estimates(tmp_path, photo_manifest):
    """composite stores a scene's estimated maps in the shared cache (it used to pass
    no cache at all), so a second run reads them instead of estimating again."""
    from click.testing import CliRunner

    from zcomp_cli.cli import cli

    root = tmp_path / "cache"
    manifest = photo_manifest(tmp_path)
    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(tmp_path / "o1"),
                                 "--cache-dir", str(root), "--renderer", "naive"])
    assert r.exit_code == 0, r.output
    entries = sorted(p.name for p in (root / "estimates").iterdir())
    assert entries, "no estimate was cached"
    mtimes = {p: p.stat().st_mtime_ns for p in (root / "estimates").iterdir()}
    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(tmp_path / "o2"),
                                 "--cache-dir", str(root), "--renderer", "naive"])
    assert r.exit_code == 0, r.output
    assert {p: p.stat().st_mtime_ns for p in (root / "estimates").iterdir()} == mtimes


@pytest.mark.blender
@pytest.mark.slow
def test_render_intrinsics_then_composite_hits_the_cache(tmp_path, examples_dir):
    """An object rendered by `render-intrinsics` is not rendered again by `composite`."""
    import json

    from click.testing import CliRunner

    from zcomp_cli.cli import cli

    root = tmp_path / "cache"
    manifest = examples_dir / "jobs.yaml"
    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(tmp_path / "c1"),
                                 "--cache-dir", str(root), "--jobs", "0", "--renderer", "naive"])
    assert r.exit_code == 0, r.output
    first = json.loads((tmp_path / "c1" / "summary.json").read_text())["blender"]
    assert first["cached"] == 0
    report = json.loads(next((tmp_path / "c1").glob("*/report.json")).read_text())
    pose = report["pose"]
    K = report["scene"]["K"]
    W, H = report["scene"]["size"]
    # the same object and pose through render-intrinsics: a cache hit, no new entry
    entries = sorted((root / "intrinsics").rglob("meta.json"))
    r = CliRunner().invoke(cli, ["-q", "render-intrinsics", "--mesh", str(examples_dir / "objects" / "vase.glb"),
                                 "--position", *map(repr, pose["position"]),
                                 "--quaternion", *map(repr, pose["quaternion"]),
                                 "--height", repr(pose["height"]),
                                 "--K", f"{K[0][0]!r},{K[1][1]!r},{K[0][2]!r},{K[1][2]!r}",
                                 "--resolution", str(W), str(H), "--out", str(tmp_path / "ri"),
                                 "--cache-dir", str(root)])
    assert r.exit_code == 0, r.output
    assert sorted((root / "intrinsics").rglob("meta.json")) == entries
    r = CliRunner().invoke(cli, ["-q", "composite", str(manifest), "--out", str(tmp_path / "c2"),
                                 "--cache-dir", str(root), "--jobs", "0", "--renderer", "naive"])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "c2" / "summary.json").read_text())["blender"]["cached"] == 1
