"""The light stage (light/stage.py, light/fit.py, light/written.py): a scene's light fitted
once per scene through the cache, the same tree given back filled, written in the
manifest's own syntax and given back frozen (the composite reproduced, an edit
followed), the renderers' settings given back, each parameter recovered with the others
frozen at the truth, and no module default read where a config is passed."""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from zcomp_cli.light.config import LightConfig
from zcomp_cli.light.stage import LightInputs, SceneLight
from zcomp_cli.maps import SceneMaps
from zcomp_cli.scene.lightparams import LightParams, Origin, Param, SkyParams, SunParams
from zcomp_cli.testing import floor_scene, write_floor_batch

SMALL = LightConfig(n_light_candidates=64, max_resolution=96, shadow_resolution=96, max_receivers=800,
                    max_fit_pixels=800)


def _scene(**kw):
    base = dict(with_box=True, box_center=(-0.4, -3.2), ambient=0.3, sky_occlusion=True, light_dir=(0.7, 1.0, 0.2))
    base.update(kw)
    return floor_scene(96, 72, **base)


def _inputs(s, key="s0"):
    return LightInputs.of(SceneMaps(s.depth, s.normals, s.albedo), s.shading, None, s.camera, key)


def _angle(a, b):
    return math.degrees(math.acos(float(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


# -- once per scene, through the cache ------------------------------------------------

def test_a_scenes_light_is_fitted_once_and_read_back_from_the_cache(tmp_path):
    s = _scene()
    stage = SceneLight(SMALL, tmp_path / "lights")
    a = stage.get(_inputs(s), None, 469)
    assert a.how == "fitted" and stage.fits == 1 and a.posterior is not None and a.evidence is not None
    b = stage.get(_inputs(s), None, 469)
    assert b.how == "memory" and stage.fits == 1 and b.model is a.model
    # another process (a shard, a Ray worker): the cache's entry, exactly the same light
    other = SceneLight(SMALL, tmp_path / "lights")
    c = other.get(_inputs(s), None, 469)
    assert c.how == "cache" and other.fits == 0
    assert json.dumps(c.model.to_dict()) == json.dumps(a.model.to_dict()) and c.params == a.params
    np.testing.assert_array_equal(c.posterior.log_post, a.posterior.log_post)
    np.testing.assert_array_equal(c.evidence.ratio, a.evidence.ratio)
    # another seed, tree or config is another entry
    assert other.get(_inputs(s), None, 470).how == "fitted"
    assert SceneLight(dataclasses.replace(SMALL, cone_samples=4), tmp_path / "lights").key(_inputs(s), LightParams.estimate(), 469) != stage.key(_inputs(s), LightParams.estimate(), 469)


def test_a_light_fitted_by_other_code_is_fitted_again(tmp_path, monkeypatch):
    """The key holds the code's digest: a change that moves the fit but no config value
    (an edit, an upgrade) does not read the light the code before it fitted."""
    import zcomp_cli.light.stage as stage_mod

    s = _scene()
    first = SceneLight(SMALL, tmp_path)
    first.get(_inputs(s), None, 469)
    assert SceneLight(SMALL, tmp_path).get(_inputs(s), None, 469).how == "cache"
    d = stage_mod.code_digest()
    assert len(d) == 16 and d == stage_mod.code_digest()
    before = first.key(_inputs(s), LightParams.estimate(), 469)
    monkeypatch.setattr(stage_mod, "code_digest", lambda: "another code")
    other = SceneLight(SMALL, tmp_path)
    assert other.key(_inputs(s), LightParams.estimate(), 469) != before
    assert other.get(_inputs(s), None, 469).how == "fitted" and other.fits == 1


def test_a_damaged_cache_entry_is_fitted_again(tmp_path):
    s = _scene()
    SceneLight(SMALL, tmp_path).get(_inputs(s), None, 1)
    (entry,) = tmp_path.glob("*.npz")
    entry.write_bytes(b"not an npz")
    again = SceneLight(SMALL, tmp_path)
    assert again.get(_inputs(s), None, 1).how == "fitted" and again.fits == 1


def test_a_fit_that_fails_fails_every_ask_with_its_reason():
    from zcomp_cli.errors import InputError

    s = _scene()
    below = LightParams(suns=(SunParams(direction=Param.given((0.0, -1.0, 0.0))),), pitch_deg=-25.0, roll_deg=0.0)
    stage = SceneLight(SMALL)
    for _ in range(2):
        with pytest.raises(InputError, match="below the horizon"):
            stage.get(_inputs(s), below, 1)
    assert stage.fits == 0


def test_a_batch_of_two_scenes_over_two_shards_fits_each_light_once(tmp_path):
    """8 jobs on 2 scenes, split over 2 shards (each its own process's stage, sharing the
    cache): each scene's light is fitted once, counted through the cache and the jobs'
    ledgers; each scene's fitted light is written as OUT/lights/<scene>.yaml."""
    from zcomp_cli.pipeline.batch import run_batch
    from zcomp_cli.pipeline.manifest import load_manifest

    manifest = write_floor_batch(tmp_path / "b", 8, n_scenes=2, size=(64, 48))
    m = load_manifest(manifest)
    cache = tmp_path / "cache"
    out = tmp_path / "out"
    for shard in ((0, 2), (1, 2)):
        summary = run_batch(m, out, cache_dir=cache, shard=shard)
        assert all(st.status == "done" for st in summary.statuses), [st.reason for st in summary.statuses]
    assert len(list((cache / "lights").glob("*.npz"))) == 2
    ledgers = [json.loads(p.read_text())["light_stage"] for p in sorted(out.glob("*/report.json"))]
    assert len(ledgers) == 8
    assert sum(led["status"] == "run" for led in ledgers) == 2
    assert len({led["key"] for led in ledgers}) == 2
    for name in ("s0", "s1"):
        assert (out / "lights" / f"{name}.yaml").is_file()
    # a second run of the same batch fits nothing: every light from the cache
    summary = run_batch(m, tmp_path / "out2", cache_dir=cache)
    again = [json.loads(p.read_text())["light_stage"] for p in sorted((tmp_path / "out2").glob("*/report.json"))]
    assert len(again) == 8 and all(led["status"] == "skipped" for led in again)


# -- the tree comes back filled --------------------------------------------------------

def test_the_fit_gives_the_same_tree_back_filled():
    s = _scene()
    f = SceneLight(SMALL).get(_inputs(s), None, 469)
    tree = f.params
    # (the searched light drawn as its posterior's modes: a node per mode, in the model's order)
    assert len(tree.suns) == len(f.model.suns) >= 1 and len(tree.lamps) == len(f.model.lamps)
    for sun, drawn in zip(tree.suns, f.model.suns):
        assert sun.direction.value is not None and not sun.direction.frozen and sun.direction.origin is Origin.SHADOWS
        assert sun.radius_deg.value == pytest.approx(drawn.radius_deg)
        assert np.allclose(np.asarray(sun.irradiance.value) / math.pi, drawn.irradiance)
    assert tree.sky.radiance_sh.value is not None and not tree.sky.radiance_sh.frozen
    assert LightParams.from_dict(tree.to_dict()) == tree


# -- written, given back, edited -------------------------------------------------------

def _manifest(folder: Path, light_line: str) -> Path:
    """A one-scene manifest of write_floor_batch's first scene with ``light_line`` added."""
    src = write_floor_batch(folder, 2, n_scenes=1, size=(64, 48))
    data = yaml.safe_load(src.read_text())
    if light_line:
        data["scenes"]["s0"]["light"] = light_line
    src.write_text(yaml.safe_dump(data))
    return src


def test_the_fitted_light_given_back_frozen_reproduces_the_composite(tmp_path):
    from zcomp_cli.imageio import read_image
    from zcomp_cli.pipeline.batch import run_batch
    from zcomp_cli.pipeline.manifest import load_manifest

    first = _manifest(tmp_path / "a", "")
    run_batch(load_manifest(first), tmp_path / "out_a", cache_dir=tmp_path / "cache")
    light = tmp_path / "out_a" / "lights" / "s0.yaml"
    doc = yaml.safe_load(light.read_text())
    assert {"pitch_deg", "roll_deg", "exposure", "light"} <= set(doc)
    kinds = [x["type"] for x in doc["light"]]
    assert "sky" in kinds and all("from" in x for x in doc["light"])
    back = _manifest(tmp_path / "b", str(light))
    run_batch(load_manifest(back), tmp_path / "out_b", cache_dir=tmp_path / "cache")
    for job in sorted(p.name for p in (tmp_path / "out_a").glob("0*")):
        a = read_image(tmp_path / "out_a" / job / "composite.exr")
        b = read_image(tmp_path / "out_b" / job / "composite.exr")
        assert np.abs(a - b).max() <= 1e-6, job
    rep = json.loads((tmp_path / "out_b" / "000_s0_card" / "report.json").read_text()) \
        if (tmp_path / "out_b" / "000_s0_card").exists() else None
    if rep is not None:  # the frozen tree: nothing to fit, the fit's exposure 1
        assert rep["renderer"]["info"]["light"]["fit"]["exposure"] == pytest.approx(1.0)


def test_a_sun_turned_in_the_written_light_turns_the_shadow(tmp_path):
    """Edited (the sun turned by 30 deg about up), the given-back light lights the
    object from there: its shadow moves."""
    s = _scene()
    f = SceneLight(SMALL).get(_inputs(s), None, 469)
    from zcomp_cli.light.written import light_document

    doc = light_document(f.params, f.model.up, f.model.up_from)
    from zcomp_cli.pipeline.lightspec import parse_light, to_params

    probs = []
    back = parse_light(doc["light"], "light", lambda *a: probs.append(a))
    assert not probs
    back = dataclasses.replace(back, pitch_deg=doc["pitch_deg"], roll_deg=doc["roll_deg"],
                               exposure=Param.given(1.0))
    same = SceneLight(SMALL).get(_inputs(s, "s1"), back, 469)
    assert np.allclose(same.model.suns[0].direction, f.model.suns[0].direction, atol=1e-9)
    assert np.allclose(same.model.sky.radiance_sh, f.model.sky.radiance_sh, atol=1e-9)
    assert np.allclose(same.model.suns[0].irradiance, f.model.suns[0].irradiance, rtol=1e-9)
    turned = [dict(x) for x in doc["light"]]
    sun = next(x for x in turned if x["type"] == "sun")
    sun["azimuth_deg"] = (sun["azimuth_deg"] + 30.0 + 180.0) % 360.0 - 180.0
    t = parse_light(turned, "light", lambda *a: probs.append(a))
    assert not probs and t is not None
    t = dataclasses.replace(t, pitch_deg=doc["pitch_deg"], roll_deg=doc["roll_deg"], exposure=Param.given(1.0))
    moved = SceneLight(SMALL).get(_inputs(s, "s2"), t, 469)
    d0, d1 = f.model.suns[0].direction, moved.model.suns[0].direction
    up = f.model.up
    flat = lambda d: d - (d @ up) * up  # noqa: E731
    assert _angle(flat(d0), flat(d1)) == pytest.approx(30.0, abs=1e-6)


def test_the_manifest_takes_every_form_it_writes(tmp_path):
    """A light file (light: path) and its keys pasted in: the same tree; a bad one is
    refused naming the light file and the field."""
    from zcomp_cli.errors import ManifestError
    from zcomp_cli.pipeline.manifest import load_manifest

    s = _scene()
    f = SceneLight(SMALL).get(_inputs(s), None, 469)
    from zcomp_cli.light.written import write_light_yaml

    lf = tmp_path / "light.yaml"
    write_light_yaml(lf, f, "s0")
    by_file = load_manifest(_manifest(tmp_path / "a", str(lf))).scenes["s0"].light
    pasted = yaml.safe_load(lf.read_text())
    src = write_floor_batch(tmp_path / "b", 2, n_scenes=1, size=(64, 48))
    data = yaml.safe_load(src.read_text())
    data["scenes"]["s0"].update(pasted)
    src.write_text(yaml.safe_dump(data))
    by_keys = load_manifest(src).scenes["s0"].light
    assert by_file == by_keys and by_file.exposure.frozen and by_file.sky.radiance_sh.frozen
    assert by_file.suns[0].angles_from is Origin.SHADOWS and by_file.suns[0].radius_deg.origin is not Origin.MANIFEST
    bad = yaml.safe_load(lf.read_text())
    bad["light"][0]["from"] = {"direction": "guessed"}
    lf.write_text(yaml.safe_dump(bad))
    with pytest.raises(ManifestError, match=r"light.yaml.*from\.direction.*unknown origin"):
        load_manifest(_manifest(tmp_path / "c", str(lf)))


# -- the settings given back -------------------------------------------------------------

def test_the_physical_settings_in_a_report_are_taken_back_with_the_same_images():
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.renderers.physical import PhysicalRenderer

    s = _scene()
    known = np.ones(s.depth.shape, bool)
    known[30:45, 30:50] = False
    req = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera)
    r = PhysicalRenderer(n_light_candidates=64, search={"temperature": 7.0})
    out = r.render([req, req])
    settings = json.loads(json.dumps(out.info["settings"]))  # as report.json holds them
    settings.pop("name")
    again = PhysicalRenderer(**settings)
    assert again.settings() == r.settings()
    np.testing.assert_array_equal(again.render([req, req]).images[0], out.images[0])


def test_the_cycles_settings_in_a_report_are_taken_back():
    from zcomp_cli.renderers.cycles import CyclesRenderer

    r = CyclesRenderer(samples=8, light={"search": {"temperature": 5.0}})
    settings = json.loads(json.dumps(r.settings()))
    settings.pop("name")
    assert CyclesRenderer(**settings).settings() == r.settings()


# -- each parameter recovered with the others frozen at the truth -----------------------

def _truth_tree(s, **free) -> LightParams:
    """The analytic scene's true light as a frozen tree (a uniform sky of radiance
    ``ambient``, a sun of ``light_intensity`` shading), ``free`` naming what to leave out."""
    from zcomp_cli.light.fit import sh_camera_to_world
    from zcomp_cli.light import atoms as at
    from zcomp_cli.worldframe import ground_frame, pitch_roll_from_up

    up = s.up_cam
    frame = ground_frame(up)
    lobe = at.sky_lobes(frame)[0][1]  # the uniform upper-hemisphere sky of radiance 1
    sky_sh = np.repeat(lobe[:, None], 3, 1) * s.ambient
    k = free.get("exposure_scale", 1.0)
    sun = SunParams(direction=Param.free() if "direction" in free else Param.given(tuple(s.light_dir_cam)),
                    radius_deg=Param.free() if "radius" in free else Param.given(float(s.meta.get("sun_radius_deg", 0.0))),
                    irradiance=Param.free() if "split" in free else Param.given(math.pi * s.light_intensity / k))
    sky = SkyParams() if "split" in free else SkyParams(radiance_sh=Param.given(sh_camera_to_world(sky_sh, frame) / k))
    pitch, roll = pitch_roll_from_up(up)
    return LightParams(suns=(sun,), sky=sky, pitch_deg=pitch, roll_deg=roll,
                       exposure=Param.free() if "exposure_scale" in free else Param.given(1.0))


def test_freeze_all_but_one_and_recover_it():
    """Mitsuba's check of a parameter tree: with every other value frozen at the truth,
    the free one is recovered through the public entry point."""
    s = _scene(sun_radius_deg=4.0)
    s.meta["sun_radius_deg"] = 4.0
    stage = SceneLight(SMALL)
    # the direction
    f = stage.get(_inputs(s, "d"), _truth_tree(s, direction=True), 469)
    assert _angle(f.model.suns[0].direction, s.light_dir_cam) < 8.0
    # the radius: within a factor 2 of the truth (the choice among radii_deg)
    f = stage.get(_inputs(s, "r"), _truth_tree(s, radius=True), 469)
    assert 2.0 <= f.model.suns[0].radius_deg <= 8.0 and f.model.suns[0].radius_from is Origin.SHADOWS
    # the split: the sky's share of the lit floor
    f = stage.get(_inputs(s, "s"), _truth_tree(s, split=True), 469)
    true_share = s.ambient / (s.ambient + s.light_intensity * float(s.light_dir_cam @ s.up_cam))
    assert abs(f.model.ambient_share() - true_share) < 0.1
    # the exposure: every strength given in units 2.5 times too small
    f = stage.get(_inputs(s, "e"), _truth_tree(s, exposure_scale=2.5), 469)
    assert f.model.fit.exposure == pytest.approx(2.5, rel=0.08)
    assert f.params.exposure.value == pytest.approx(2.5, rel=0.08) and not f.params.exposure.frozen


# -- no module default read where a config is passed -----------------------------------

def test_no_module_reads_a_default_config_where_one_is_passed(monkeypatch):
    """With the renderer's settings passed down, no module builds a config of its own
    defaults: every config class's no-argument construction is trapped while a scene's
    light is fitted and a job rendered (a given light, a box's shadow, a probe)."""
    from zcomp_cli.knobs import config_classes
    from zcomp_cli.renderers.base import RenderRequest
    from zcomp_cli.renderers.physical import PhysicalRenderer
    from zcomp_cli.renderers.physical.settings import PhysicalSettings

    r = PhysicalRenderer(n_light_candidates=48)
    s = _scene()
    known = np.ones(s.depth.shape, bool)
    known[30:45, 30:50] = False
    reqs = [RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera, scene_key=k)
            for k in ("est",)]
    given = LightParams(suns=(SunParams(direction=Param.given(tuple(s.light_dir_cam))),))
    reqs.append(RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera, scene_key="given",
                              light=given))

    def trap(cls):
        init = cls.__init__

        def guarded(self, *a, **kw):
            if not a and not kw:
                raise AssertionError(f"{cls.__name__}() built from its defaults inside the render")
            init(self, *a, **kw)

        monkeypatch.setattr(cls, "__init__", guarded)

    for cls in config_classes(PhysicalSettings):
        trap(cls)
    for req in reqs:
        out = r.render([req, req])
        assert np.all(np.isfinite(out.images[1]))


def test_a_free_size_is_the_same_on_one_thread_and_on_many(monkeypatch):
    """A given sun with a free size: its candidate radii are scored on the pool's threads
    by a scorer made for it, whose noise scales the first radius sets (the others only
    read them): the light is the same, to the bit, on one thread and on three."""
    from zcomp_cli.scene import raycast

    s = _scene(sun_radius_deg=4.0)
    s.meta["sun_radius_deg"] = 4.0
    fits = []
    for n in ("1", "3"):
        monkeypatch.setenv("OMP_NUM_THREADS", n)
        monkeypatch.setattr(raycast, "MIN_THREAD_RAYS", 64)
        f = SceneLight(SMALL).get(_inputs(s, "r"), _truth_tree(s, radius=True), 469)
        fits.append([np.asarray(v, np.float64) for v in (f.model.suns[0].radius_deg, f.model.suns[0].irradiance,
                                                         f.model.fit.residual, f.model.sky.radiance_sh)])
    for a, b in zip(*fits):
        np.testing.assert_array_equal(a, b)
    assert fits[0][0] > 0
