"""Cast shadows on the support tied to what casts them
(renderers/physical/shadow_evidence.py): on analytic floor scenes with exact shadows
(zcomp_cli.testing), the tied dark pixels against the exact shadow, an off-frame
occluder's shadow left out, invariance to texture and exposure, degenerate input; the
reach and the lit level's basis on synthetic grids."""

import numpy as np
import pytest

from zcomp_cli.scene.depthmesh import build_depth_mesh
from zcomp_cli.scene.frame import scene_up
from zcomp_cli.light.config import EvidenceConfig
from zcomp_cli.light.evidence import (ShadowEvidence, lit_basis, shadow_basins, shadow_evidence,
                                                          within_reach)
from zcomp_cli.testing import floor_scene

W, H = 160, 120
# the box's shadow falls to the camera's right; an occluder outside the frustum, far
# left, throws its own into the frame's left
LIGHT = (-0.6, 0.8, 0.3)
BOX = dict(with_box=True, box_center=(-0.3, -3.2), box_size=(0.6, 0.8, 0.6), sky_occlusion=False)
OFF_FRAME = [((-3.2, -3.6), (0.8, 1.6, 0.8))]


def _scene(light=LIGHT, **kw):
    return floor_scene(W, H, light_dir=light, **{**BOX, **kw})


def _evidence(s, shading=None, albedo=None, mesh_of=None):
    """(mesh, evidence) of a scene; ``shading``/``albedo`` (h, w, 3) override the scene's;
    ``mesh_of``: another scene whose geometry to use (same camera)."""
    g = s if mesh_of is None else mesh_of
    up, _ = scene_up(None, g.normals, g.depth > 0)
    m = build_depth_mesh(g.depth, g.normals, g.camera, up)
    sh = (s.shading if shading is None else shading).mean(-1)
    al = (s.albedo if albedo is None else albedo).mean(-1)
    ev = shadow_evidence(sh, m.support, m.casters, m.points, up, known=s.depth > 0, albedo=al, labels=m.labels)
    return m, ev


def _checker(square: int, low: float = 0.4) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    return np.where(((yy // square) + (xx // square)) % 2 == 0, 1.0, low)[..., None]


def test_shapes_and_ranges():
    s = _scene()
    m, ev = _evidence(s)
    assert isinstance(ev, ShadowEvidence)
    for a in (ev.ratio, ev.weight, ev.lit_level, ev.shading, ev.soft_mask):
        assert a.shape == (H, W)
    for a in (ev.dark, ev.tied, ev.reach):
        assert a.shape == (H, W) and a.dtype == bool
    assert ev.basis.shape[:2] == (H, W)
    # tied within dark within the support; weight 0 or 1, and 0 off the support
    assert not (ev.tied & ~ev.dark).any() and not (ev.dark & ~m.support).any()
    assert set(np.unique(ev.weight)) <= {0.0, 1.0} and not ev.weight[~m.support].any()
    assert np.isnan(ev.ratio[~m.support]).all()
    assert not (ev.reach & ~m.support).any() and not (ev.tied & ~ev.reach).any()
    # the ratio is about 1 where lit, below it where dark
    lit = np.isfinite(ev.ratio) & ~ev.dark
    assert abs(float(np.median(ev.ratio[lit])) - 1.0) < 0.01 and (ev.ratio[ev.dark] < 1.0).all()
    assert ev.shown and 0 < ev.sigma < 0.1
    sm = ev.soft_mask
    assert sm.min() >= 0 and sm.max() <= 1 and not sm[~ev.tied].any() and sm[ev.tied].max() > 0.9


@pytest.mark.parametrize("light", [(0.7, 1.0, 0.2), LIGHT, (0.5, 0.7, 0.6), (0.3, 1.0, -0.5)])
def test_tied_dark_pixels_cover_the_exact_shadow(light):
    s = _scene(light)
    m, ev = _evidence(s)
    true = m.support & (s.visibility < 0.5)
    lit = m.support & (s.visibility > 0.99)
    assert true.sum() > 150
    assert (ev.tied & true).sum() > 0.6 * true.sum()
    assert (ev.tied & lit).sum() < 0.05 * lit.sum()
    # the umbra's ratio is the sky's share of the lit floor
    share = s.ambient / (s.ambient + s.light_intensity * max(float(s.light_dir_cam @ s.up_cam), 0.0))
    core = ev.tied & true & (s.visibility == 0)
    assert abs(float(np.median(ev.ratio[core])) - share) < 0.03


def test_an_off_frame_occluders_shadow_is_dark_but_not_tied():
    s0 = _scene()
    s = _scene(occluders=OFF_FRAME)
    m, ev = _evidence(s)
    # the occluder is outside the frustum: the frame's geometry is the box scene's
    assert np.array_equal(s.depth > 0, s0.depth > 0) and np.allclose(s.depth, s0.depth)
    box_shadow = m.support & (s0.visibility < 0.5)
    off = m.support & (s.visibility < 0.5) & ~(s0.visibility < 0.5)
    assert off.sum() > 50
    read = off & np.isfinite(ev.ratio)
    assert ev.dark[read].mean() > 0.9
    assert not ev.tied[off].any() and not ev.weight[off].any()
    # the box's own shadow is still tied, as without the other occluder
    _, ev0 = _evidence(s0)
    assert (ev.tied & box_shadow).sum() > 0.6 * box_shadow.sum()
    assert np.array_equal(ev.tied, ev0.tied)


def test_exposure_invariance():
    s = _scene()
    _, a = _evidence(s)
    _, b = _evidence(s, shading=s.shading * 7.0)
    assert np.array_equal(a.dark, b.dark) and np.array_equal(a.tied, b.tied)
    assert np.array_equal(a.weight, b.weight)
    np.testing.assert_allclose(b.ratio, a.ratio, rtol=1e-6, equal_nan=True)
    np.testing.assert_allclose(b.lit_level, 7.0 * a.lit_level, rtol=1e-6, equal_nan=True)
    assert abs(a.sigma - b.sigma) < 1e-9


@pytest.mark.parametrize("square", [8, 16, 40])
def test_a_textured_floor_leaves_each_readable_pixels_ratio_unchanged(square):
    """Texture (a checkerboard albedo; the image follows it, the shading is unchanged):
    its edges are unread (weight 0), every other pixel reads as without it."""
    s = _scene()
    _, plain = _evidence(s)
    _, tex = _evidence(s, albedo=s.albedo * _checker(square))
    read = np.isfinite(tex.ratio)
    assert 0.2 < read.sum() / np.isfinite(plain.ratio).sum() < 1.0  # the edges' bands are left out
    assert not (read & ~np.isfinite(plain.ratio)).any()
    np.testing.assert_allclose(tex.ratio[read], plain.ratio[read], rtol=1e-6)
    assert np.array_equal(tex.dark[read], plain.dark[read])
    assert not tex.weight[~read].any()
    assert abs(tex.sigma - plain.sigma) < 1e-6


def test_a_texture_far_from_the_shadow_leaves_the_tied_shadow_unchanged():
    s = _scene()
    m, plain = _evidence(s)
    # the floor's left third a darker material: one edge, far from the box's shadow
    alb = s.albedo.copy()
    alb[:, : W // 3] *= 0.5
    _, tex = _evidence(s, albedo=alb)
    assert np.array_equal(tex.tied, plain.tied) and plain.tied.sum() > 150


def test_a_checkerboard_floor_leaves_the_tied_shadow_unchanged():
    s = _scene()
    m, plain = _evidence(s)
    _, tex = _evidence(s, albedo=s.albedo * _checker(12))
    read = np.isfinite(tex.ratio)
    true = m.support & (s.visibility < 0.5) & read
    assert true.sum() > 100 and tex.dark[true].mean() > 0.9  # every readable shadow pixel is dark...
    # ...and, as without the texture, tied to the box
    assert (tex.tied & true).sum() > 0.9 * (plain.tied & true).sum()


def test_without_a_caster_nothing_is_tied():
    # the same shading, read with the box's geometry taken away: its shadow is no cast
    # shadow the photograph ties to anything
    s = _scene()
    bare = floor_scene(W, H, light_dir=LIGHT, sky_occlusion=False)
    m, ev = _evidence(s, mesh_of=bare)
    assert not m.casters.any()
    assert ev.dark.sum() > 150 and not ev.tied.any() and not ev.shown and not ev.reach.any()
    assert not ev.weight[ev.dark].any()


def _banded(s, band, strip=None, band_ratio=0.4, strip_ratio=0.9):
    """The scene's shading with an unseen occluder's band (``band_ratio`` of the light)
    and a shallower ``strip`` (a wall's foot, which the wall's occlusion of the sky
    shades a little), both (H, W) bool."""
    f = np.ones((H, W))
    f[band] = band_ratio
    if strip is not None:
        f[strip & ~band] = strip_ratio
    return s.shading * f[..., None]


def test_a_band_over_a_third_of_the_floor_leaves_the_open_floor_lit():
    # the lit level fitted coarse to fine: a cubic fitted at once bends into the band
    # and reads the open floor beside it at 0.91 of its level (0.82 at the 5th
    # percentile), as the shipped example's job 0 did
    s = _scene()
    band = np.mgrid[0:H, 0:W][1] < W // 3
    m, ev = _evidence(s, shading=_banded(s, band))
    lit = m.support & ~band & (s.visibility > 0.99) & np.isfinite(ev.ratio)
    assert lit.sum() > 0.4 * m.support.sum()
    assert abs(float(np.median(ev.ratio[lit])) - 1.0) < 0.01
    assert float(np.percentile(ev.ratio[lit], 5)) > 0.97
    inside = m.support & band & np.isfinite(ev.ratio)
    assert abs(float(np.median(ev.ratio[inside])) - 0.4) < 0.03 and ev.dark[inside].mean() > 0.95


def test_an_unseen_band_joined_to_the_shadow_by_a_shallower_strip_is_not_tied():
    # the band stands clear of the box, but a strip along the floor (at 0.9 of the
    # light) joins it to the box's shadow: one dark region, two basins. Only the box's
    # is tied (as one region, the band was tied wherever the box could reach)
    s = _scene()
    yy, xx = np.mgrid[0:H, 0:W]
    band = xx < 22
    strip = ((yy >= 62) & (yy < 68) & (xx < 106)) | ((xx >= 100) & (xx < 106) & (yy >= 45) & (yy < 68))
    m, ev = _evidence(s, shading=_banded(s, band, strip))
    box_shadow = m.support & (s.visibility < 0.5)
    assert not (band & m.casters).any() and (box_shadow & strip).any()
    assert ev.dark[band & m.support & np.isfinite(ev.ratio)].mean() > 0.95
    assert ev.dark[strip & ~band & np.isfinite(ev.ratio)].mean() > 0.95
    assert not ev.tied[band].any() and not ev.weight[band & ev.dark].any()
    assert (ev.tied & box_shadow).sum() > 0.9 * box_shadow.sum()
    # the band within the box's reach: had it been tied, it would have been there
    assert (ev.reach & band & ev.dark).sum() > 100


def test_shadow_basins_known_values():
    h, w = 20, 40
    r = np.ones((h, w))
    r[5:15, 2:10] = 0.4   # one shadow
    r[5:15, 30:38] = 0.3  # another
    r[8:11, 10:30] = 0.9  # joined by a shallower strip
    region = r < 0.95
    n, lab = shadow_basins(r, region, 0.05, 0.0)
    assert n == 3 and lab.shape == (h, w) and lab.dtype == np.int32
    assert not lab[~region].any() and lab[region].min() >= 1
    a, b = lab[10, 5], lab[10, 34]
    assert a != b and (lab[5:15, 2:10] == a).all() and (lab[5:15, 30:38] == b).all()
    assert set(np.unique(lab[8:11, 10:30])) == {a, b}
    # a pass less than the depth above the shallower basin: one basin
    r2 = r.copy()
    r2[8:11, 10:30] = 0.42
    n, lab = shadow_basins(r2, region, 0.05, 0.0)
    assert n == 2 and len(np.unique(lab[region])) == 1
    # one shadow over a checker's tiles whose albedo is read 5 % off either way (0.38
    # and 0.42, nan on the unread edges between them) is one basin: no pass rises
    # between its parts by the depth (which is the dark threshold, at least three times
    # the lit floor's own misfit: 5 % of the lit level there, 2 % of the shadow's)
    r3 = np.ones((h, w))
    r3[4:16, 4:36] = np.where((np.arange(4, 36) // 4) % 2 == 0, 0.38, 0.42)[None, :]
    r3[4:16, 8::8] = np.nan
    reg3 = np.isnan(r3) | (r3 < 0.95)
    reg3[:, :4] = reg3[:, 36:] = reg3[:4] = reg3[16:] = False
    n, lab = shadow_basins(r3, reg3, 0.05, 1.0)
    assert n == 2 and (lab[reg3] == 1).all()
    # an empty region, or nothing read
    n, lab = shadow_basins(r, np.zeros((h, w), bool), 0.05, 1.0)
    assert n == 1 and not lab.any()
    n, lab = shadow_basins(np.full((h, w), np.nan), region, 0.05, 1.0)
    assert n == 1 and not lab.any()


@pytest.mark.parametrize("case", ["no support", "all nan", "all zero", "unknown"])
def test_degenerate_input_gives_empty_masks(case):
    s = _scene()
    up, _ = scene_up(None, s.normals, s.depth > 0)
    m = build_depth_mesh(s.depth, s.normals, s.camera, up)
    sh, sup, known = s.shading.mean(-1), m.support, None
    if case == "no support":
        sup = np.zeros_like(m.support)
    elif case == "all nan":
        sh = np.full_like(sh, np.nan)
    elif case == "all zero":
        sh = np.zeros_like(sh)
    else:
        known = np.zeros_like(m.support)
    ev = shadow_evidence(sh, sup, m.casters, m.points, up, known=known, albedo=s.albedo.mean(-1), labels=m.labels)
    assert ev.ratio.shape == (H, W) and np.isnan(ev.ratio).all()
    assert not ev.dark.any() and not ev.tied.any() and not ev.reach.any() and not ev.weight.any()
    assert not ev.shown and not ev.soft_mask.any()


def _ground_grid(h=60, w=80):
    """Points on the plane y = 0 (up +y): x in [-4, 4], z in [-10, -2]."""
    x = np.linspace(-4, 4, w)
    z = np.linspace(-10, -2, h)
    P = np.stack(np.broadcast_arrays(x[None, :], np.zeros((h, w)), z[:, None]), -1).astype(np.float64)
    return P


def test_within_reach_is_four_heights_along_the_ground():
    P = _ground_grid()
    h, w = P.shape[:2]
    up = np.array([0.0, 1.0, 0.0])
    casters = np.zeros((h, w), bool)
    casters[28:32, 38:42] = True
    P[casters, 1] = np.linspace(0.0, 0.5, int(casters.sum()))  # a post 0.5 m high
    support = ~casters
    reach = within_reach(P, casters, up, support)
    C = P[casters][:, [0, 2]]
    d = np.min(np.linalg.norm(P[..., None, [0, 2]] - C[None, None], axis=-1), axis=-1)
    want = support & (d <= EvidenceConfig().reach_heights * 0.5)
    # within a hair of the bound either way
    edge = np.abs(d - EvidenceConfig().reach_heights * 0.5) < 1e-6
    assert np.array_equal(reach & ~edge, want & ~edge) and want.sum() > 50 and (support & ~want).sum() > 1000
    # twice as high: twice as far
    P2 = P.copy()
    P2[casters, 1] *= 2
    d2 = within_reach(P2, casters, up, support)
    assert (d2 & ~reach).sum() > 0 and not (reach & ~d2).any()
    # no caster, or one not above the support: no reach
    assert not within_reach(P, np.zeros_like(casters), up, support).any()
    P3 = P.copy()
    P3[casters, 1] = -0.2
    assert not within_reach(P3, casters, up, support).any()


def test_within_reach_per_component():
    P = _ground_grid()
    h, w = P.shape[:2]
    up = np.array([0.0, 1.0, 0.0])
    labels = np.zeros((h, w), np.int64)
    labels[10:12, 10:12] = 1  # a tall post
    labels[50:52, 70:72] = 2  # a short one
    P[labels == 1, 1] = 1.0
    P[labels == 2, 1] = 0.1
    casters = labels > 0
    support = ~casters
    one = within_reach(P, casters, up, support)  # one caster: the tallest's height for all
    each = within_reach(P, casters, up, support, labels)
    assert not (each & ~one).any() and (one & ~each).sum() > 20
    # near the short post, only 0.4 m
    near_short = np.linalg.norm(P[..., [0, 2]] - P[50, 70, [0, 2]], axis=-1)
    assert not (each & (near_short > 0.6) & (near_short < 3.0)).any()


def test_lit_basis_columns():
    P = _ground_grid()
    h, w = P.shape[:2]
    up = np.array([0.0, 1.0, 0.0])
    ok = np.ones((h, w), bool)
    X = lit_basis(P, up, ok, degree=2, albedo_spread=EvidenceConfig().albedo_spread)
    assert X.shape == (h, w, 6)
    np.testing.assert_allclose(X[..., 0], 1.0)
    np.testing.assert_allclose(X[ok][:, 1:3].mean(0), 0.0, atol=1e-9)
    np.testing.assert_allclose(X[ok][:, 1:3].std(0), 1.0, atol=1e-9)
    np.testing.assert_allclose(X[..., 3], X[..., 1] ** 2)
    np.testing.assert_allclose(X[..., 4], X[..., 1] * X[..., 2])
    # every monomial up to the degree: (d + 1)(d + 2) / 2 of them
    assert lit_basis(P, up, ok, degree=3, albedo_spread=EvidenceConfig().albedo_spread).shape == (h, w, 10)
    # a constant albedo adds nothing, a varying one its log and the log's square
    assert lit_basis(P, up, ok, np.full((h, w), 0.5), degree=2, albedo_spread=EvidenceConfig().albedo_spread).shape == (h, w, 6)
    a = np.where(np.arange(w)[None, :] < w // 2, 0.2, 0.8) * np.ones((h, 1))
    Xa = lit_basis(P, up, ok, a, degree=2, albedo_spread=EvidenceConfig().albedo_spread)
    assert Xa.shape == (h, w, 8)
    np.testing.assert_allclose(Xa[ok][:, 6].mean(), 0.0, atol=1e-9)
    np.testing.assert_allclose(Xa[..., 7], Xa[..., 6] ** 2)
    # the lit level's fit: a quadratic log shading is spanned exactly
    u, v = X[..., 1], X[..., 2]
    y = 0.3 - 0.2 * u + 0.1 * v + 0.05 * u * v
    beta = np.linalg.lstsq(X[ok], y[ok], rcond=None)[0]
    np.testing.assert_allclose(X[ok] @ beta, y[ok], atol=1e-9)


# a wall 1.5 m high across the frame, 5 m ahead, its top edge seen against the sky (a
# caster where ``sky_edges_cast``: test_depthmesh); the sky (ambient 1.0) the wall hides
# darkens its foot
TOPPED_WALL = [((0.0, -5.0), (30.0, 1.5, 0.3))]


def _walled(light):
    from zcomp_cli.scene.config import MeshConfig
    from zcomp_cli.scene.skyvis import support_sky_view

    s = floor_scene(W, H, pitch_deg=-10.0, occluders=TOPPED_WALL, light_dir=light, sky_occlusion=True,
                    ambient=1.0, light_intensity=0.4)
    up, _ = scene_up(None, s.normals, s.depth > 0)
    m = build_depth_mesh(s.depth, s.normals, s.camera, up, cfg=MeshConfig(sky_edges_cast=True))
    view = support_sky_view(m.points, m.support, m.up, m.caster(), directions=256, stride=2, bias_rel=1e-3)
    return s, m, up, view


def _read(s, m, up, **kw):
    return shadow_evidence(s.shading.mean(-1), m.support, m.casters, m.points, up, known=s.depth > 0,
                           albedo=s.albedo.mean(-1), labels=m.labels, **kw)


def test_the_sky_a_wall_hides_is_the_lit_levels_not_a_shadow():
    # the sun in front of the wall: its foot is darker only by the sky the wall hides
    # (the light's 0.94 there at 0.64 of the sky). Without the sky's term, that foot is
    # read as the wall's cast shadow (thousands of pixels tied); with it, as lit
    s, m, up, view = _walled((0.3, 1.0, 0.8))
    assert (s.visibility[m.support] > 0.99).all()  # no cast shadow at all
    foot = m.support & (view < 0.85)
    assert foot.sum() > 500
    bare = _read(s, m, up)
    assert bare.tied[foot].mean() > 0.9
    ev = _read(s, m, up, sky_view=view, sky_share=0.52)
    assert ev.dark.sum() < 0.01 * foot.sum() and not ev.tied.any()
    assert ev.basis.shape[-1] == bare.basis.shape[-1] + 1  # (the term joins the lit level's basis)


def test_a_walls_cast_shadow_is_read_past_the_sky_it_hides():
    # the sun behind the wall: its top edge casts a band on the floor, tied to the wall,
    # and with the sky's term nothing else is dark
    s, m, up, view = _walled((0.3, 1.0, -0.8))
    shadow = m.support & (s.visibility < 0.5)
    assert shadow.sum() > 1000
    ev = _read(s, m, up, sky_view=view, sky_share=0.52)
    assert (ev.tied & shadow).sum() > 0.9 * shadow.sum()
    assert not (ev.dark & ~shadow).any()


def test_a_sky_view_that_does_not_vary_changes_nothing():
    s = _scene()
    up, _ = scene_up(None, s.normals, s.depth > 0)
    m = build_depth_mesh(s.depth, s.normals, s.camera, up)
    a = _read(s, m, up)
    b = _read(s, m, up, sky_view=np.ones((H, W)), sky_share=0.52)
    for x, y in ((a.ratio, b.ratio), (a.lit_level, b.lit_level), (a.basis, b.basis)):
        np.testing.assert_array_equal(x, y)
    assert (a.tied == b.tied).all()


def test_the_light_stage_reads_the_sky_view_where_its_directions_are_set():
    # the scorer's evidence (``search.search_scorer``): with ``sky_view_directions`` the
    # lit level has the sky's term (one more basis column) and the wall's foot is lit;
    # by default (0: off, design notes) neither
    import dataclasses

    from zcomp_cli.light import search as sr
    from zcomp_cli.light.config import DEFAULT_LIGHT
    from zcomp_cli.light.prepare import prepare

    s = floor_scene(W, H, pitch_deg=-10.0, occluders=TOPPED_WALL, light_dir=(0.3, 1.0, 0.8), sky_occlusion=True,
                    ambient=1.0, light_intensity=0.4)
    known = s.depth > 0
    up, _ = scene_up(None, s.normals, known)
    walls = dataclasses.replace(DEFAULT_LIGHT, mesh=dataclasses.replace(DEFAULT_LIGHT.mesh, sky_edges_cast=True))
    on = dataclasses.replace(walls, evidence=dataclasses.replace(walls.evidence, sky_view_directions=256))
    pp = prepare(s.depth, s.normals, s.shading, known, s.albedo, s.camera, up, walls)
    off, _ = sr.search_scorer(pp, walls)
    ev, _ = sr.search_scorer(pp, on)
    assert ev.basis.shape[-1] == off.basis.shape[-1] + 1
    assert off.tied.sum() > 100 and ev.tied.sum() < 0.1 * off.tied.sum()


def test_a_pixel_that_sees_no_sky_under_the_skys_whole_share_stays_finite():
    # sky_share 1 (all the light the sky's) and a pixel with no sky: the factor is 0,
    # its log floored (``EvidenceConfig.min_sky_factor``) so that the fit still runs and
    # stays finite
    s = _scene()
    up, _ = scene_up(None, s.normals, s.depth > 0)
    m = build_depth_mesh(s.depth, s.normals, s.camera, up)
    view = np.ones((H, W))
    view[m.support & (np.mgrid[0:H, 0:W][1] < 10)] = 0.0
    ev = _read(s, m, up, sky_view=view, sky_share=1.0)
    bare = _read(s, m, up)
    # finite wherever the lit level is read at all (the support less its unread outline)
    assert (np.isfinite(ev.lit_level) == np.isfinite(bare.lit_level)).all()
    assert (np.isfinite(ev.ratio) == np.isfinite(bare.ratio)).all()
    assert np.isfinite(ev.basis[m.support]).all() and ev.shown


def test_a_sky_view_of_another_shape_or_a_share_outside_0_1_is_refused():
    s = _scene()
    up, _ = scene_up(None, s.normals, s.depth > 0)
    m = build_depth_mesh(s.depth, s.normals, s.camera, up)
    with pytest.raises(ValueError, match="sky_view is"):
        _read(s, m, up, sky_view=np.ones((H, W + 1)), sky_share=0.5)
    with pytest.raises(ValueError, match="outside"):
        _read(s, m, up, sky_view=np.ones((H, W)), sky_share=1.5)
