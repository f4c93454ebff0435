"""Each job's ledger (report.json's ``stages``, ``pipeline.ledger``): every stage run or
skipped, why, and its time; and the work a scene does not need left out (DESIGN.md
section 6, issue 49): a given light not searched, a light given whole fitted without the
depth mesh, a scene's light fitted once (memory, then cache), provided maps not
estimated, the glossy prefilter built only for a glossy object, once per scene."""

import json

import numpy as np
import yaml

from zcomp_cli.pipeline.batch import run_batch
from zcomp_cli.pipeline.manifest import load_manifest


def _manifest(sw, folder, *, light=None, jobs=2, glossy=False, renderer="physical"):
    """The sweep's nominal scene with ``jobs`` jobs of its sphere (given ``light``;
    ``glossy``: the sphere with roughness and metallic maps)."""
    path = sw.build_scene(sw.Case("range", "nominal"), folder, sw.renderer_spec(renderer, False))
    m = yaml.safe_load(path.read_text())
    if light is not None:
        m["scenes"]["s"]["light"] = light
    m["jobs"] = [{**m["jobs"][0], "output": f"job{k}"} for k in range(jobs)]
    if glossy:
        from zcomp_cli.imageio import write_exr

        mask = np.ones((48, 64), np.float32)
        write_exr(folder / "sphere" / "roughness.exr", 0.3 * mask)
        write_exr(folder / "sphere" / "metallic.exr", 0.0 * mask)
    path.write_text(yaml.safe_dump(m, sort_keys=False))
    return path


def _ledgers(out, n=2):
    reps = [json.loads((out / f"job{k}" / "report.json").read_text()) for k in range(n)]
    return [{e["stage"]: e for e in r["stages"]} for r in reps], reps


def _well_formed(stages: dict):
    for name, e in stages.items():
        assert e["status"] in ("run", "skipped"), e
        assert (e["why"] is None) == (e["status"] == "run"), e
        assert e["seconds"] is None or e["seconds"] >= 0, e
    assert list(stages)[-1] == "write"


def test_an_estimated_light_is_fitted_once_and_the_ledger_says_so(stability_sweep, tmp_path):
    path = _manifest(stability_sweep, tmp_path / "a")
    run_batch(load_manifest(path), tmp_path / "out", cache_dir=tmp_path / "cache")
    (first, second), _ = _ledgers(tmp_path / "out")
    for st in (first, second):
        _well_formed(st)
    assert first["scene"]["status"] == "run" and first["scene.maps"]["why"] == "maps provided"
    assert first["object"]["why"].startswith("bundle given")
    assert first["light"]["status"] == "run"
    assert first["light.search"]["status"] == "run" and first["light.shadows"]["status"] == "run"
    assert first["render.shadow_reach"]["why"].startswith("light estimated")
    assert first["render.gloss"]["why"].startswith("nothing glossy")
    assert first["render.prefilter"]["why"] == "nothing glossy reads it"
    # the scene's second job: its scene and light kept
    assert second["scene"]["status"] == "skipped" and "earlier job" in second["scene"]["why"]
    assert second["light"]["why"].startswith("fitted for an earlier job") and "light.search" not in second
    # another run sharing the cache: the light is a cache hit
    run_batch(load_manifest(path), tmp_path / "out2", cache_dir=tmp_path / "cache")
    (again, _), _ = _ledgers(tmp_path / "out2")
    assert again["light"]["why"].startswith("cache hit")


def test_a_light_given_whole_is_not_searched_and_builds_no_depth_mesh(stability_sweep, tmp_path, monkeypatch):
    """The probe and the sun given, their strengths in physical units: only the exposure
    is free. Before: the depth mesh and its Embree caster were built for every fit (0.5 s
    of the shipped example's job 4, read by nothing)."""
    import zcomp_cli.scene.depthmesh as dm

    built = []
    real = dm.build_depth_mesh
    monkeypatch.setattr(dm, "build_depth_mesh", lambda *a, **k: built.append(1) or real(*a, **k))
    from zcomp_cli.imageio import write_exr

    (tmp_path / "a").mkdir()
    write_exr(tmp_path / "a" / "probe.exr", np.full((16, 32, 3), 0.3, np.float32))
    light = [{"type": "probe", "hdr": "probe.exr"},
             {"type": "sun", "direction": [0.3, 0.8, 0.5], "angular_radius_deg": 1.0, "irradiance": 3.0}]
    path = _manifest(stability_sweep, tmp_path / "a", light=light, jobs=1)
    run_batch(load_manifest(path), tmp_path / "out", cache_dir=tmp_path / "cache")
    (st,), (rep,) = _ledgers(tmp_path / "out", 1)
    _well_formed(st)
    assert st["light.search"] == {"stage": "light.search", "status": "skipped", "why": "light given", "seconds": None}
    assert st["light.shadows"]["status"] == "skipped" and st["light.shadows"]["why"].startswith("light given whole")
    assert st["light.probe"]["status"] == "run" and st["light.solve"]["what"] == "the exposure only"
    assert st["render.shadow_reach"]["status"] == "run"
    assert not built
    # a given sun whose size is left to the photograph does read its shadows
    light[1].pop("angular_radius_deg")
    path = _manifest(stability_sweep, tmp_path / "b", light=light, jobs=1)
    (tmp_path / "b" / "probe.exr").write_bytes((tmp_path / "a" / "probe.exr").read_bytes())
    run_batch(load_manifest(path), tmp_path / "out_b", cache_dir=tmp_path / "cache")
    (st,), _ = _ledgers(tmp_path / "out_b", 1)
    assert st["light.shadows"]["status"] == "run" and st["light.search"]["why"] == "light given" and built


def test_the_glossy_prefilter_is_built_for_a_glossy_object_once_per_scene(stability_sweep, tmp_path):
    path = _manifest(stability_sweep, tmp_path / "a", glossy=True)
    run_batch(load_manifest(path), tmp_path / "out", cache_dir=tmp_path / "cache")
    (first, second), _ = _ledgers(tmp_path / "out")
    assert first["render.gloss"]["status"] == "run"
    assert first["render.prefilter"]["status"] == "run" and first["render.prefilter"]["seconds"] > 0
    assert second["render.prefilter"]["why"].startswith("built for an earlier job")


def test_a_renderer_that_draws_no_light_fits_none(stability_sweep, tmp_path):
    path = _manifest(stability_sweep, tmp_path / "a", renderer="naive", jobs=1)
    run_batch(load_manifest(path), tmp_path / "out", cache_dir=tmp_path / "cache")
    (st,), _ = _ledgers(tmp_path / "out", 1)
    _well_formed(st)
    assert st["light"]["why"] == "the renderer draws no light of its own" and "render.gloss" not in st


def test_estimated_maps_are_in_the_ledger(photo_manifest, tmp_path):
    path = photo_manifest(tmp_path, "naive")
    run_batch(load_manifest(path), tmp_path / "out", cache_dir=tmp_path / "cache")
    rep = json.loads(next((tmp_path / "out").glob("*/report.json")).read_text())
    st = {e["stage"]: e for e in rep["stages"]}
    assert "scene.maps" not in st
    depth = st["scene.maps.depth"]
    assert depth["status"] == "run" and "ground_plane" in depth["what"]
    assert {"scene.maps.normals", "scene.maps.albedo"} <= set(st)
    assert st["object"]["what"] == "a 2D object stood on the support"
