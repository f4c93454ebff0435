"""The light fitted to the photograph (light/search.py, light/fit.py): invariants on
analytic scenes ray cast with a sky the boxes hide (zcomp_cli.testing), not branches."""

import numpy as np
import pytest

from zcomp_cli.scene.lightmodel import ShadowKind
from zcomp_cli.scene.frame import scene_up
from zcomp_cli.testing import estimate_light, floor_scene


def _angle(a, b):
    """Degrees between ``a`` and ``b``; atan2 of the cross and dot products, exact near 0
    (an arccos of a dot product near 1 reads float noise as a micro-degree)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)))


def _estimate(s, shading=None, **kw):
    known = s.depth > 0
    up, uf = scene_up(None, s.normals, known)
    return estimate_light(s.depth, s.normals, s.shading if shading is None else shading, known, s.albedo,
                          s.camera, up=up, up_from=uf, **kw)


def _scene(light=(0.7, 1.0, 0.2), **kw):
    base = dict(with_box=True, box_center=(-0.4, -3.2), ambient=0.3, sky_occlusion=True)
    base.update(kw)
    return floor_scene(160, 120, light_dir=light, **base)


def test_direction_from_a_visible_cast_shadow():
    s = _scene()
    m = _estimate(s)
    assert m.shadows is ShadowKind.CAST and len(m.suns) + len(m.lamps) == 1
    assert _angle(m.key_direction, s.light_dir_cam) < 10.0
    # the split: a full shadow keeps the sky's share of the lit floor
    true_share = s.ambient / (s.ambient + s.light_intensity * float(s.light_dir_cam @ s.up_cam))
    assert abs(m.ambient_share() - true_share) < 0.1
    assert m.fit.shadow_blocks > 0.1 and m.fit.uncertainty_deg < 20


def test_an_off_frame_occluders_shadow_does_not_cancel_a_visible_one():
    # a second box far left, outside the frustum, casts its shadow into the frame
    s = _scene(occluders=[((-3.2, -3.6), (0.8, 1.6, 0.8))])
    assert (s.visibility < 1).sum() > 0
    m = _estimate(s)
    assert m.shadows is ShadowKind.CAST
    assert _angle(m.key_direction, s.light_dir_cam) < 12.0


def test_exposure_invariance():
    s = _scene()
    a, b = _estimate(s), _estimate(s, shading=s.shading * 7.0)
    assert _angle(a.key_direction, b.key_direction) < 1e-6
    assert np.allclose(b.suns[0].irradiance, 7.0 * a.suns[0].irradiance, rtol=1e-3)
    assert np.allclose(b.sky.radiance_sh, 7.0 * a.sky.radiance_sh, rtol=1e-3, atol=1e-9)
    assert a.suns[0].radius_deg == pytest.approx(b.suns[0].radius_deg, rel=1e-6)


def test_a_bare_floor_draws_the_posteriors_modes_at_the_lights_size():
    """Nothing on a bare floor fixes the light's direction: the posterior is vague, and
    the light is drawn as what the posterior says -- its likeliest directions, each a
    light as faint as its mass, the rest of the mass as sky -- each at the light's own
    size (the default: no shadow shows its penumbra), never widened to stand for the
    doubt; the report says why and lists the modes."""
    from zcomp_cli.light.config import DEFAULT_LIGHT
    from zcomp_cli.scene.lightmodel import Origin
    from zcomp_cli.scene.lightparams import SUN_RADIUS_DEG

    s = floor_scene(120, 90, light_dir=(0.3, 1.0, 0.4), ambient=0.3, sky_occlusion=True)
    m = _estimate(s)
    assert m.shadows is ShadowKind.CAST and m.fit.unfixed
    assert 2 <= len(m.suns) + len(m.lamps) <= DEFAULT_LIGHT.search.max_modes
    for sun in m.suns:
        assert sun.radius_deg == SUN_RADIUS_DEG and sun.radius_from is Origin.DEFAULT
    modes = m.fit.modes
    assert len(modes) == len(m.suns) + len(m.lamps)
    shares = [x["share"] for x in modes]
    assert shares == sorted(shares, reverse=True) and 0.0 < sum(shares) < 0.9
    assert m.fit.uncertainty_deg > 30.0 and "within" in m.fit.note and "the rest of the posterior as sky" in m.fit.note
    # each sun as strong as its mass (the rest of the light is in the sky)
    e = np.array([float(x.irradiance.mean()) for x in m.suns])
    np.testing.assert_allclose(e / e.sum(), np.array(shares) / sum(shares), atol=2e-3)
    # the support's level is still explained
    lit = float(s.shading[s.depth > 0].mean())
    on_up = float(m.sky.shading(m.up[None])[0].mean()) + sum(
        float(x.irradiance.mean()) * float(max(x.direction @ m.up, 0.0)) for x in m.suns)
    assert abs(on_up - lit) / lit < 0.15
    assert m.to_info()["fallback"]


def test_the_size_comes_from_the_penumbra_or_is_forced():
    """The radius is the one rule's choice among ``search.radii_deg`` and the Sun's (by
    the likelihoods of its cone-averaged shadow): a 10 deg sun's soft shadow gives a
    wide light read off the shadows, a crisp one's the Sun's own (within a factor of two,
    or under 2 deg where the truth is under 1: issue 47's target), and the renderer's
    ``shadow_softness`` forces one."""
    from zcomp_cli.scene.lightparams import SUN_RADIUS_DEG
    from zcomp_cli.scene.lightmodel import Origin
    from zcomp_cli.light.config import DEFAULT_LIGHT as DEFAULTS, LightConfig

    s = _scene(sun_radius_deg=10.0, box_size=(0.6, 1.2, 0.6))
    m = _estimate(s)
    sun = m.suns[0]
    assert len(m.suns) == 1 and not m.fit.unfixed
    assert sun.radius_from is Origin.SHADOWS and sun.radius_deg in DEFAULTS.search.radii_deg
    assert 5.0 <= sun.radius_deg <= 20.0, sun.radius_deg
    crisp = _estimate(_scene(box_size=(0.6, 1.2, 0.6))).suns[0]
    assert crisp.radius_deg < 2.0 and (crisp.radius_deg == SUN_RADIUS_DEG) == (crisp.radius_from is Origin.DEFAULT)
    f = _estimate(s, cfg=LightConfig(shadow_softness=3.0))
    assert f.suns[0].radius_deg == 3.0 and f.suns[0].radius_from is Origin.MANIFEST


def test_too_few_pixels_give_the_prior():
    s = floor_scene(40, 30)
    known = np.zeros(s.depth.shape, bool)
    m = estimate_light(s.depth, s.normals, s.shading, known, s.albedo, s.camera, up=np.array([0, 1.0, 0]))
    assert m.shadows is ShadowKind.CONTACT and "too few" in m.fit.note
    assert np.all(np.isfinite(m.sky.radiance_sh))


# 12 analytic scenes: lights around the sky, the box at a few places, with and without a
# back wall (the analytic wall has no top: with it, the light comes from the camera's
# side, else it would light nothing). The estimate must find the direction on the whole;
# the tolerance leaves room for a neutral change (a few degrees) without admitting a
# wrong light.
SCENES = [((0.7, 1.0, 0.2), (-0.4, -3.2), False), ((-0.6, 0.8, 0.3), (0.3, -3.0), False),
          ((0.2, 1.0, 0.6), (-0.2, -3.4), True), ((-0.8, 0.6, -0.4), (0.4, -3.6), False),
          ((0.9, 0.5, 0.1), (-0.6, -3.0), True), ((0.1, 1.0, 0.5), (0.0, -3.8), False),
          ((-0.3, 0.7, -0.7), (0.5, -3.2), False), ((0.5, 0.9, 0.3), (-0.5, -3.5), True),
          ((-0.9, 0.9, 0.0), (0.2, -3.3), False), ((0.6, 0.6, 0.6), (-0.3, -3.1), False),
          ((-0.4, 1.0, 0.4), (0.6, -3.6), True), ((0.3, 0.8, 0.8), (-0.1, -3.0), False)]


@pytest.mark.slow
def test_aggregate_direction_accuracy_on_analytic_scenes():
    errs = []
    for light, centre, wall in SCENES:
        s = _scene(light=light, box_center=centre, with_wall=wall, box_size=(0.6, 0.9, 0.6))
        m = _estimate(s)
        errs.append(180.0 if m.key_direction is None or m.shadows is not ShadowKind.CAST
                    else _angle(m.key_direction, s.light_dir_cam))
    errs = np.asarray(errs)
    assert np.median(errs) < 10.0, errs
    assert (errs < 25.0).mean() >= 0.8, errs


def test_an_unseen_occluders_shadow_alone_fixes_no_direction():
    """The shipped example's job 0 failure: a dark band cast by something outside the
    frame, with nothing in the frame to tie it to, must not be read as a confident light
    (the old fit drew a hard shadow to the wrong side): the posterior stays vague and no
    drawn light holds much of it."""
    s = floor_scene(160, 120, light_dir=(-0.9, 0.8, -0.2), ambient=0.3, sky_occlusion=True,
                    occluders=[((-3.0, -3.6), (0.8, 1.6, 0.8))])
    assert (s.visibility[s.depth > 0] < 0.5).mean() > 0.02  # the band is there
    m = _estimate(s)
    assert m.fit.uncertainty_deg > 25.0 and m.fit.unfixed
    assert m.fit.modes[0]["share"] < 0.5


def test_a_confident_shadow_is_one_light_and_a_vague_one_many_faint_ones():
    """The drawn light follows the posterior, not its spread: where a cast shadow fixes
    the direction, one light holding nearly all of it; on a bare floor, several, none
    holding much -- and the same size in both (the size is the penumbra's, not the
    doubt's)."""
    crisp = _estimate(_scene())
    bare = _estimate(floor_scene(120, 90, light_dir=(0.7, 1.0, 0.2), ambient=0.3, sky_occlusion=True))
    assert len(crisp.suns) == 1 and not crisp.fit.unfixed and crisp.fit.modes[0]["share"] > 0.9
    assert len(bare.suns) + len(bare.lamps) > 1 and bare.fit.unfixed and bare.fit.modes[0]["share"] < 0.5
    # the vague light is drawn at the Sun's size, never at its doubt's; the crisp one
    # (a point sun) no wider than the depth mesh's caster lets its shadow be read: at
    # this size the mesh's box casts a slightly different shadow than the true one, and
    # a 4 deg cone fits that difference by one tempered unit (docs/design-notes.md,
    # "The radius's margin moves with the temperature")
    assert all(x.radius_deg < 2.0 for x in bare.suns)
    assert all(x.radius_deg <= 4.0 for x in crisp.suns)
    # the chance that the cues mislead is stated beside the doubt, not drawn: the crisp
    # light's doubt is its cues' own (a few degrees), and the report reads back
    from zcomp_cli.light.config import DEFAULT_LIGHT
    from zcomp_cli.scene.lightmodel import FitSummary

    assert crisp.fit.misled == DEFAULT_LIGHT.search.misled > 0 and crisp.fit.uncertainty_deg < 10.0
    assert bare.fit.uncertainty_deg > 3 * crisp.fit.uncertainty_deg
    assert FitSummary.from_info(crisp.fit.to_info()).misled == crisp.fit.misled


@pytest.mark.parametrize("position", [(0.5, 1.5, -3.0), (1.5, 1.0, -2.5), (-1.0, 2.0, -4.0)])
def test_a_lamps_pool_of_light_places_it_where_no_shadow_shows(position):
    """A lamp over a bare floor casts no shadow the photograph shows, but its pool of
    light (the falloff with distance and angle) says where it hangs: the photometric
    likelihood, at the noise of the best candidate of every kind (a sun cannot explain a
    pool), finds a low lamp and is sure of it. A high lamp's pool is broad (a sun and the
    sky explain most of it): found, or the estimate says it does not know -- never a
    confident wrong light."""
    s = floor_scene(160, 120, ambient=0.3, sky_occlusion=True, light_intensity=0.0, lamp=(position, 3.0))
    m = _estimate(s)
    true = np.asarray(s.meta["lamp_cam"], np.float64)
    # (the heaviest mode first: the light the report names)
    found = len(m.lamps) >= 1 and np.linalg.norm(m.lamps[0].position - true) < 0.3 * np.linalg.norm(true)
    if position[1] <= 1.5:
        assert found and len(m.lamps) == 1 and not m.suns and m.fit.uncertainty_deg < 15.0
    else:
        assert found or (m.fit.unfixed and m.fit.uncertainty_deg > 30.0)


def test_the_size_rule_keeps_the_default_unless_another_beats_it_by_the_odds():
    """``search.picked_radius``: the likeliest radius at the posterior's temperature,
    unless the default (the first, the Sun's) is within ``default_radius_odds`` of it."""
    from zcomp_cli.light.search import picked_radius
    from zcomp_cli.scene.lightparams import SUN_RADIUS_DEG, Origin

    radii = (SUN_RADIUS_DEG, 1.0, 4.0)
    ll = np.array([0.0, 5.0, 12.0])
    assert picked_radius(radii, ll, 10.0, 1.0) == (4.0, Origin.SHADOWS)  # 1.2 units ahead
    assert picked_radius(radii, ll, 10.0, 1.5) == (SUN_RADIUS_DEG, Origin.DEFAULT)  # not 1.5 ahead
    assert picked_radius(radii, ll, 1.0, 100.0) == (SUN_RADIUS_DEG, Origin.DEFAULT)
    assert picked_radius(radii, ll, 10.0, 0.0) == (4.0, Origin.SHADOWS)  # no odds: the likeliest
    assert picked_radius(radii, np.array([3.0, 1.0, 2.0]), 10.0, 0.0) == (SUN_RADIUS_DEG, Origin.DEFAULT)


def test_a_sun_has_the_suns_size_as_its_default_and_a_lamp_no_typical_size():
    """``search.default_odds``: the fitted odds for a sun, none for a lamp (a bulb, a
    panel, a softbox alike), so a lamp is drawn at the size its shadows like best."""
    import dataclasses

    from zcomp_cli.light.config import LightConfig
    from zcomp_cli.light.search import FitLight, default_odds

    cfg = LightConfig()
    cfg = dataclasses.replace(cfg, search=dataclasses.replace(cfg.search, default_radius_odds=2.5))
    sun = FitLight("sun", np.array([0.0, 1.0, 0.0]), None, np.zeros(0))
    lamp = FitLight("lamp", np.array([0.0, 2.0, -3.0]), None, np.zeros(0))
    assert default_odds(sun, cfg) == 2.5 and default_odds(lamp, cfg) == 0.0
