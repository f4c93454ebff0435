"""Cast-shadow evidence on textured floors: a tile's albedo is no shadow.

Image over albedo is not the shading alone: a glossy floor adds nearly the same
radiance to a dark tile as to a bright one, so on a checker floor the bright tiles
read darker than the dark ones around them. The darkness map compares each pixel with
pixels of its own albedo (``same_material_level``)."""

import numpy as np
import pytest

from zcomp_cli.conventions import luminance
from zcomp_cli.renderers.physical import estimate_lighting
from zcomp_cli.renderers.physical.evidence import darkness_map, same_material_level
from zcomp_cli.testing import floor_scene

GLOSS = 0.08  # added radiance, the same on every tile (a glossy reflection)
SUN = (0.7, 1.0, 0.2)


def _checker_floor(s, tile_m=0.5, dark=0.12, bright=0.7):
    """The scene re-lit on a checker floor: albedo by world (x, z) tile, image =
    albedo * shading + GLOSS; returns (albedo, observed shading image / albedo)."""
    pts = s.camera.unproject(s.depth) @ s.cam_to_world.T + s.camera_origin
    tile = (np.floor(pts[..., 0] / tile_m) + np.floor(pts[..., 2] / tile_m)) % 2 == 0
    floor = (s.depth > 0) & (np.abs(pts[..., 1]) < 1e-3)
    alb = np.where((floor & tile)[..., None], bright, np.where(floor[..., None], dark, s.albedo))
    image = alb * s.shading + GLOSS * (s.depth > 0)[..., None]
    return alb.astype(np.float32), (image / np.maximum(alb, 1e-3)).astype(np.float32)


def _dark(s, shading, albedo=None):
    alb_lum = None if albedo is None else luminance(albedo)
    return darkness_map(luminance(shading), s.normals.astype(np.float64), s.depth > 0, s.up_cam, s.depth,
                        albedo=alb_lum)


def test_checker_tiles_read_level_against_their_own_albedo():
    s = floor_scene(112, 84, light_dir=SUN, ambient=0.3)
    alb, shading = _checker_floor(s)
    e_plain, usable = _dark(s, shading)
    e_alb, usable2 = _dark(s, shading, alb)
    bright = usable & (alb[..., 0] > 0.5)
    # the failure: on image / albedo the bright tiles read as faint shadows everywhere
    assert np.median(e_plain[bright]) > 0.15
    # against tiles of their own albedo they are level
    assert np.percentile(np.abs(e_alb[usable2]), 95) < 0.03


def test_a_real_shadow_on_a_checker_floor_keeps_its_darkness():
    s = floor_scene(112, 84, with_box=True, light_dir=SUN, ambient=0.3, box_center=(-0.4, -3.2))
    alb, shading = _checker_floor(s)
    e, usable = _dark(s, shading, alb)
    shadow = usable & (s.visibility < 0.5)
    assert shadow.sum() > 30
    for tile in (alb[..., 0] > 0.5, alb[..., 0] < 0.5):
        sel = shadow & tile
        # the darkness the shadow really has on that tile: 1 - (a S_sh + g) / (a S_lit + g)
        a = alb[sel][:, 0]
        lit = s.ambient + s.light_intensity * max(s.up_cam @ s.light_dir_cam, 0.0)
        want = 1.0 - (a * s.ambient + GLOSS) / (a * lit + GLOSS)
        assert abs(np.median(e[sel]) - np.median(want)) < 0.06


def test_sun_recovered_on_a_glossy_checker_floor():
    s = floor_scene(112, 84, with_box=True, light_dir=SUN, ambient=0.3, box_center=(-0.4, -3.2))
    alb, shading = _checker_floor(s)
    est = estimate_lighting(s.depth, s.normals, shading, s.depth > 0, s.camera, n_candidates=128,
                            march_steps=16, max_fit_pixels=2000, albedo=alb)
    assert est.fallback is None and est.direction_source == "cast shadows of visible geometry"
    cos = est.direction @ s.light_dir_cam
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))) < 10.0


def test_same_material_level_known_values_and_degenerate_albedo():
    v = np.ones((20, 30))
    v[:, 15:] = 3.0
    w = np.ones((20, 30))
    # two materials side by side: each pixel's level is its own material's
    alb = np.where(np.arange(30)[None] < 15, 0.1, 0.8) * np.ones((20, 1))
    lvl = same_material_level(v, w, 6.0, alb)
    assert np.allclose(lvl[:, :15], 1.0, atol=1e-4) and np.allclose(lvl[:, 15:], 3.0, atol=1e-4)
    # one material: the plain blur, which mixes them
    assert not np.allclose(same_material_level(v, w, 6.0, np.full((20, 30), 0.5))[:, 14], 1.0, atol=0.1)
    # non-finite and zero albedo: finite levels
    bad = alb.copy()
    bad[0, 0], bad[1, 1], bad[2, 2], bad[3, 3] = np.nan, np.inf, 0.0, -1.0
    assert np.all(np.isfinite(same_material_level(v, w, 6.0, bad)))
    # no weight at all: the values themselves
    assert np.array_equal(same_material_level(v, np.zeros((20, 30)), 6.0, alb), v)


@pytest.mark.parametrize("shape", [(1, 1), (3, 200)])
def test_same_material_level_tiny_maps(shape):
    v = np.random.default_rng(0).uniform(0.5, 1.5, shape)
    out = same_material_level(v, np.ones(shape), 4.0, np.random.default_rng(1).uniform(0.05, 0.9, shape))
    assert out.shape == shape and np.all(np.isfinite(out))
