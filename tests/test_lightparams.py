"""The light as one parameter tree (lightparams.py) built from manifest mappings
(pipeline/lightspec.py): what is given is frozen, what is left out or ``auto`` free; the
estimated tree; the cache key; a sun's direction from its angles."""

import dataclasses
import math

import numpy as np
import pytest

from zcomp_cli.scene.lightparams import (LAMP_RADIUS_M, SUN_RADIUS_DEG, WHITE, LampParams, LightParams, Origin, Param,
                                   ProbeParams, SunParams)
from zcomp_cli.pipeline.lightspec import parse_light, scene_light, to_params
from zcomp_cli.worldframe import direction_from_angles


def _parse(value):
    probs = []
    out = parse_light(value, "scenes.s.light", lambda c, k, w, m: probs.append((w, m)))
    assert not probs, probs
    assert isinstance(out, LightParams)
    return out


def _free(p: Param) -> bool:
    return isinstance(p, Param) and p.value is None and not p.frozen


def _given(p: Param, value) -> bool:
    return isinstance(p, Param) and p.frozen and p.value == value and p.origin is Origin.MANIFEST


def test_param_given_and_free():
    g, f = Param.given(2.0), Param.free()
    assert g.frozen and g.value == 2.0 and g.origin is Origin.MANIFEST
    assert not f.frozen and f.value is None and f.origin is Origin.FIT
    assert Param.given(1.0, Origin.PROBE).origin is Origin.PROBE and Param.free(Origin.PRIOR).origin is Origin.PRIOR
    assert g.to_dict() == {"value": 2.0, "frozen": True, "origin": "MANIFEST"}
    assert Param.given((1.0, 2.0, 3.0)).to_dict()["value"] == [1.0, 2.0, 3.0]
    with pytest.raises(dataclasses.FrozenInstanceError):
        g.value = 3.0
    assert str(Origin.MANIFEST) == "given in the manifest"


def test_sun_from_a_direction():
    sun, = _parse({"direction": [0, 2, 0]}).suns
    assert _given(sun.direction, (0.0, 1.0, 0.0)) and sun.angles is None  # normalised
    assert _free(sun.radius_deg) and _free(sun.irradiance) and sun.share is None and sun.color == WHITE
    assert sun.direction_given
    np.testing.assert_allclose(sun.direction_in([0.3, 0.9, 0.1]), [0, 1, 0])  # up does not matter


def test_sun_from_angles():
    sun, = _parse({"azimuth_deg": 135, "elevation_deg": 40}).suns
    assert sun.angles == (135.0, 40.0) and all(isinstance(a, float) for a in sun.angles)
    # the direction itself needs the scene's up: free in the tree, yet given
    assert _free(sun.direction) and sun.direction_given
    assert _free(sun.radius_deg) and _free(sun.irradiance) and sun.share is None


def test_sun_size_and_strengths():
    sun, = _parse({"direction": [1, 1, 0], "angular_radius_deg": 2, "irradiance": 3.5, "color": [1, 0.9, 0.8]}).suns
    assert _given(sun.radius_deg, 2.0) and _given(sun.irradiance, 3.5) and sun.share is None
    assert sun.color == (1.0, 0.9, 0.8)
    # the older number strength: the share against the fitted sky, the irradiance free
    sun, = _parse({"direction": [1, 1, 0], "strength": 3}).suns
    assert sun.share == 3.0 and _free(sun.irradiance)
    sun, = _parse({"direction": [1, 1, 0], "strength": 0}).suns
    assert sun.share == 0.0 and _free(sun.irradiance)
    # auto, or nothing: fitted
    for v in ({"direction": [1, 1, 0], "strength": "auto"}, {"direction": [1, 1, 0]}):
        sun, = _parse(v).suns
        assert sun.share is None and _free(sun.irradiance) and _free(sun.radius_deg)
    # "directional" is a sun
    assert len(_parse({"type": "directional", "direction": [0, 1, 0]}).suns) == 1


def test_lamp_fields():
    lamp, = _parse({"type": "lamp", "position": [0.5, 1.2, -2]}).lamps
    assert _given(lamp.position, (0.5, 1.2, -2.0))
    assert _free(lamp.power) and _free(lamp.radius_m) and lamp.facing is None and lamp.color == WHITE
    lamp, = _parse({"type": "lamp", "position": [0, 1, -2], "power": "auto", "radius_m": 0.1}).lamps
    assert _free(lamp.power) and _given(lamp.radius_m, 0.1)
    lamp, = _parse({"type": "lamp", "position": [0, 1, -2], "power": 60, "facing": [0, -3, 0],
                    "color": [1, 0.5, 0.5]}).lamps
    assert _given(lamp.power, 60.0) and _free(lamp.radius_m)
    assert lamp.facing == (0.0, -1.0, 0.0) and lamp.color == (1.0, 0.5, 0.5)


def test_probe_fields():
    tree = _parse({"type": "probe", "hdr": "set.exr"})
    p = tree.probe
    assert isinstance(p, ProbeParams) and p.hdr == "set.exr"
    assert p.rotation_deg == 0.0 and p.convention == "zcomp" and p.strength == 1.0
    assert not tree.suns and not tree.lamps and tree.given
    p = _parse({"type": "probe", "hdr": "set.exr", "rotation_deg": 90, "convention": "blender",
                "strength": 2.5}).probe
    assert (p.rotation_deg, p.convention, p.strength) == (90.0, "blender", 2.5)


def test_a_mixed_list():
    tree = _parse([{"type": "probe", "hdr": "p.exr"}, {"azimuth_deg": 30, "elevation_deg": 40, "irradiance": 2},
                   {"type": "lamp", "position": [0, 1, -2], "power": 60}])
    assert tree.probe is not None and len(tree.suns) == 1 and len(tree.lamps) == 1 and tree.given
    assert isinstance(tree.suns, tuple) and isinstance(tree.lamps, tuple)
    assert tree.pitch_deg is None and tree.roll_deg is None and tree.tilt == {}


def test_the_estimated_light():
    e = LightParams.estimate()
    assert len(e.suns) == 1 and not e.lamps and e.probe is None and not e.given
    sun = e.suns[0]
    assert _free(sun.direction) and _free(sun.radius_deg) and _free(sun.irradiance)
    assert sun.angles is None and sun.share is None and not sun.direction_given
    assert sun.direction_in([0, 1, 0]) is None
    assert e.tilt == {}
    t = LightParams.estimate(pitch_deg=-20.0, roll_deg=3.0)
    assert t.tilt == {"pitch_deg": -20.0, "roll_deg": 3.0} and not t.given
    assert LightParams.estimate(pitch_deg=-20.0).tilt == {"pitch_deg": -20.0, "roll_deg": 0.0}
    # a lamp alone, or a sun of given angles, is a given light
    assert LightParams(lamps=(LampParams(position=Param.given((0.0, 1.0, 0.0))),)).given
    assert LightParams(suns=(SunParams(angles=(10.0, 20.0)),)).given
    assert not LightParams().given


def test_scene_light_adds_the_tilt():
    assert scene_light(None, {}) is None
    est = scene_light(None, {"pitch_deg": -20.0})
    assert est.tilt == {"pitch_deg": -20.0, "roll_deg": 0.0} and not est.given and len(est.suns) == 1
    given = scene_light(_parse({"direction": [0, 1, 0]}), {"pitch_deg": -10.0, "roll_deg": 2.0})
    assert given.given and (given.pitch_deg, given.roll_deg) == (-10.0, 2.0)
    assert scene_light(_parse({"direction": [0, 1, 0]}), {}).tilt == {}


def test_the_tree_is_frozen():
    tree = _parse({"direction": [0, 1, 0]})
    with pytest.raises(dataclasses.FrozenInstanceError):
        tree.suns = ()
    with pytest.raises(dataclasses.FrozenInstanceError):
        tree.suns[0].share = 2.0
    # lists given to the tree are kept as tuples
    assert isinstance(LightParams(suns=[SunParams()]).suns, tuple)


def test_the_key_is_stable_and_tells_trees_apart():
    base = [{"type": "probe", "hdr": "p.exr", "rotation_deg": 10},
            {"azimuth_deg": 30, "elevation_deg": 40, "irradiance": 2},
            {"type": "lamp", "position": [0, 1, -2], "power": 60}]
    k0 = _parse(base).key()
    assert isinstance(k0, str) and _parse(base).key() == k0  # the same mappings, the same key
    # ints or floats in the YAML: the same light, the same key
    same = [{"type": "probe", "hdr": "p.exr", "rotation_deg": 10.0},
            {"azimuth_deg": 30.0, "elevation_deg": 40.0, "irradiance": 2.0},
            {"type": "lamp", "position": [0.0, 1.0, -2.0], "power": 60.0}]
    assert _parse(same).key() == k0

    def changed(i, **kw):
        v = [dict(x) for x in base]
        v[i].update(kw)
        return v

    variants = [changed(0, rotation_deg=11), changed(0, convention="blender"), changed(0, strength=2),
                changed(0, hdr="q.exr"), changed(1, azimuth_deg=31), changed(1, elevation_deg=41),
                changed(1, irradiance=2.5), changed(1, angular_radius_deg=1), changed(1, color=[1, 1, 0.9]),
                changed(2, position=[0, 1, -2.5]), changed(2, power="auto"), changed(2, radius_m=0.05),
                changed(2, facing=[0, -1, 0]), base[:2], base[1:]]
    keys = [_parse(v).key() for v in variants]
    assert k0 not in keys and len(set(keys)) == len(keys)
    # the tilt, and where a value came from, are part of what the light is
    tree = _parse(base)
    assert dataclasses.replace(tree, pitch_deg=-20.0, roll_deg=0.0).key() != k0
    sun = tree.suns[0]
    moved = dataclasses.replace(sun, irradiance=Param.given(2.0, Origin.PROBE))
    assert dataclasses.replace(tree, suns=(moved,)).key() != k0
    assert LightParams.estimate().key() == LightParams.estimate().key() != k0


@pytest.mark.parametrize("up", [(0.0, 1.0, 0.0), (0.0, 0.9, 0.42), (0.1, 0.95, -0.3)])
@pytest.mark.parametrize("az, el", [(0.0, 30.0), (135.0, 40.0), (-60.0, 10.0), (270.0, 90.0)])
def test_direction_in_matches_direction_from_angles(up, az, el):
    up = np.asarray(up) / np.linalg.norm(up)
    sun, = _parse({"azimuth_deg": az, "elevation_deg": el}).suns
    d = sun.direction_in(up)
    np.testing.assert_allclose(d, direction_from_angles(az, el, up), atol=1e-12)
    assert np.linalg.norm(d) == pytest.approx(1.0)
    assert math.degrees(math.asin(float(np.clip(d @ up, -1, 1)))) == pytest.approx(el, abs=1e-6)


def test_to_params_and_to_dict_round_trip():
    lights = [{"type": "sun", "direction": [0.0, 1.0, 0.0], "azimuth_deg": None, "elevation_deg": None,
               "angular_radius_deg": None, "strength": "auto", "irradiance": None, "color": None},
              {"type": "lamp", "position": [0.0, 1.0, -2.0], "radius_m": None, "power": 60.0, "facing": None,
               "color": None}]
    tree = to_params(lights, {"pitch_deg": -15.0, "roll_deg": 1.0})
    assert tree.pitch_deg == -15.0 and tree.roll_deg == 1.0
    d = tree.to_dict()
    assert d["suns"][0]["type"] == "sun" and d["lamps"][0]["type"] == "lamp" and d["probe"] is None
    assert d["suns"][0]["direction"] == {"value": [0.0, 1.0, 0.0], "frozen": True, "origin": "MANIFEST"}
    assert d["lamps"][0]["radius_m"] == {"value": None, "frozen": False, "origin": "FIT"}
    # a roll without a pitch is dropped
    assert to_params(lights, {"roll_deg": 4.0}).roll_deg is None
    # the defaults a free size falls back on are physical: the Sun's, a bulb's
    assert SUN_RADIUS_DEG == pytest.approx(0.265) and LAMP_RADIUS_M == pytest.approx(0.03)
