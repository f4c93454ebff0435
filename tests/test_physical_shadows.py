"""The physical renderer's shadows on analytic scenes: one smooth penumbra, the object's
shadow and sky occlusion from its posed mesh, degenerate meshes. (The light itself:
test_light_estimate.py, test_known_light.py.)"""

import numpy as np
import pytest

from zcomp_cli.maps import SceneMaps
from zcomp_cli.renderers.base import RenderRequest
from zcomp_cli.renderers.physical import PhysicalRenderer
from zcomp_cli.renderers.physical.softshadow import penumbra_filter
from zcomp_cli.testing import floor_scene, insert_bundle, light_context, sphere_object_bundle

SUN = (0.7, 1.0, 0.2)  # world, toward the light


def _angle(a, b):
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def test_penumbra_is_one_smooth_ramp():
    # a hard shadow edge, occluder 1 m away, 5 deg light: one monotonic ramp, no bands
    H, W = 40, 120
    vis = np.ones((H, W))
    vis[:, :60] = 0
    t_hit = np.where(vis < 1, 1.0, np.inf)
    z = np.full((H, W), 3.0)
    out = penumbra_filter(vis, t_hit, z, np.zeros((H, W), int), np.ones((H, W), bool), 300.0,
                          np.tan(np.deg2rad(5.0)))
    row = out[H // 2]
    assert np.all(np.diff(row) >= -1e-9)
    ramp = (row > 0.02) & (row < 0.98)
    assert 6 <= ramp.sum() <= 30  # about 2 * t * tan(a) * f / z = 17 px wide
    assert row[:30].max() < 0.02 and row[-30:].min() > 0.98


def test_penumbra_filter_over_a_box_matches_the_whole_frame():
    # the filter reads only the context each blur reaches: the box's values are those
    # of the whole frame's filter, two classes and a varying occluder distance included
    rng = np.random.default_rng(3)
    H, W = 90, 130
    vis = (rng.random((H, W)) > 0.4).astype(float)
    vis[:, 70:] = 1.0
    t_hit = np.where(vis < 1, rng.uniform(0.2, 3.0, (H, W)), np.inf)
    z = rng.uniform(2.0, 4.0, (H, W))
    cls = np.zeros((H, W), int)
    cls[30:60, 40:80] = 1
    valid = rng.random((H, W)) > 0.05
    whole = penumbra_filter(vis, t_hit, z, cls, valid, 300.0, np.tan(np.deg2rad(8.0)))
    for box in [(20, 35, 70, 90), (0, 0, 10, 130), (85, 100, 200, 300)]:
        part = penumbra_filter(vis, t_hit, z, cls, valid, 300.0, np.tan(np.deg2rad(8.0)), box=box)
        y0, x0, y1, x1 = box
        np.testing.assert_allclose(part, whole[y0:y1, x0:x1], atol=1e-6)


def test_penumbra_filter_blends_the_two_levels_about_each_pixels_width():
    # each level is blurred only around the pixels that take it: the values are the
    # definition's, every level blurred over the whole frame and blended per pixel
    # between the two about its penumbra's width (log2(1 + r), linearly)
    from zcomp_cli.renderers.physical.settings import TransportConfig
    from zcomp_cli.renderers.physical.softshadow import blur_reach, classwise_blur, gaussian_blur

    cfg = TransportConfig()
    rng = np.random.default_rng(8)
    H, W = 120, 160
    vis = np.ones((H, W))
    vis[30:90, 20:60] = 0.0  # a near occluder: narrow penumbra
    vis[40:100, 100:150] = 0.0  # a far one: wide
    vis[rng.random((H, W)) > 0.97] = 0.0
    t_hit = np.where(vis < 1, np.where(np.arange(W)[None] < 80, 0.1, 4.0), np.inf)
    z = np.full((H, W), 3.0)
    cls = np.zeros((H, W), int)
    cls[50:70, 110:130] = 1
    valid = rng.random((H, W)) > 0.02
    tan_a = np.tan(np.deg2rad(6.0))
    got = penumbra_filter(vis, t_hit, z, cls, valid, 300.0, tan_a, cfg=cfg)
    # the definition, written out
    v = np.where(valid, vis, 1.0)
    shadowed = valid & (v < 0.5) & np.isfinite(t_hit)
    s_ = cfg.blocker_search_px
    g_s = gaussian_blur(shadowed.astype(np.float32), s_)
    g_t = gaussian_blur(np.where(shadowed, t_hit, 0.0).astype(np.float32), s_)
    g_v = gaussian_blur(valid.astype(np.float32), s_)
    tb = np.where(g_s > 1e-4, g_t / np.maximum(g_s, 1e-4), np.where(shadowed, t_hit, 0.0))
    has = np.where(g_v > 1e-4, g_s / np.maximum(g_v, 1e-4), shadowed) > 1e-3
    r = np.clip(np.nan_to_num(np.where(has & valid, tb * tan_a * 300.0 / z, 0.0)), 0.0, cfg.max_penumbra_px)
    radii = cfg.penumbra_levels_px[:max(2, int(np.searchsorted(cfg.penumbra_levels_px, r.max())) + 1)]
    assert len(radii) >= 6 and blur_reach(radii[-1]) > 20  # the wide levels are in play
    levels = np.stack([classwise_blur(v, cls, valid, rad) for rad in radii])
    pos = np.interp(np.log2(1.0 + r), np.log2(1.0 + np.asarray(radii)), np.arange(len(radii)))
    i0 = np.clip(np.floor(pos).astype(int), 0, len(radii) - 2)
    f = pos - i0
    want = np.clip((1 - f) * np.take_along_axis(levels, i0[None], 0)[0]
                   + f * np.take_along_axis(levels, (i0 + 1)[None], 0)[0], 0.0, 1.0)
    np.testing.assert_allclose(got, want, atol=1e-12)
    assert 0.05 < got[40:100, 100:150].mean() < 0.95 and got[30:90, 20:60].mean() < 0.2


@pytest.mark.parametrize("channels", [None, 3, 6])
def test_classwise_blur_is_the_per_class_normalised_blur(channels):
    # each class cropped to the box its kernels read gives the definition's values,
    # channel by channel (the sky's visibility and the mesh's occlusion go as 6)
    from zcomp_cli.renderers.physical.softshadow import classwise_blur, normalized_blur

    rng = np.random.default_rng(4)
    H, W = 80, 100
    vals = rng.random((H, W) if channels is None else (H, W, channels))
    cls = np.zeros((H, W), int)
    cls[20:40, 30:50] = 1
    cls[:, :8] = 2
    valid = rng.random((H, W)) > 0.2
    fill = rng.random((H, W)) > 0.5
    fill[60:, 60:] = valid[60:, 60:] = False  # pixels neither valid nor filled keep their value
    planes = [vals] if channels is None else [vals[..., k] for k in range(channels)]
    for radius in (0.0, 2.0, 8.0, 32.0):
        got = classwise_blur(vals, cls, valid, radius, fill=fill)
        assert got.shape == vals.shape and got.dtype == np.float64
        for k, v in enumerate(planes):
            want = v.copy()
            for c in (0, 1, 2):
                want = np.where((valid | fill) & (cls == c), normalized_blur(v, valid & (cls == c), radius), want)
            np.testing.assert_allclose(got if channels is None else got[..., k], want, atol=1e-6)
        assert np.array_equal(got[60:, 60:], vals[60:, 60:])


def test_length_is_numpys_norm():
    # the same values as np.linalg.norm (the renderer's images do not change), any shape
    from zcomp_cli.scene.sampling import length

    rng = np.random.default_rng(2)
    v = rng.normal(size=(400, 3)) * 10.0 ** rng.integers(-3, 5, (400, 1))
    v = np.concatenate([v, [[0, 0, 0], [np.inf, 0, 1], [np.nan, 1, 1], [1e200, 1e200, 0], [1e-200, 0, 0]]])
    with np.errstate(over="ignore"):  # (1e200 squared: inf, as numpy gives)
        np.testing.assert_array_equal(length(v), np.linalg.norm(v, axis=-1))
    assert length(v[:400].reshape(20, 20, 3)).shape == (20, 20)


def test_triangle_samples_are_stratified_by_area():
    # each triangle gets the floor or the ceiling of its expected count: no clumps and
    # no gaps on a surface a shadow map must cover
    from zcomp_cli.scene.objectshadow import sample_triangles as _sample_triangles

    rng = np.random.default_rng(5)
    tri = rng.random((300, 3, 3))
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    p = area / area.sum()
    n = 2000
    pick, pts = _sample_triangles(tri, p, n)
    count = np.bincount(pick, minlength=len(tri))
    assert count.sum() == n
    assert np.all(count >= np.floor(n * p) - 1) and np.all(count <= np.ceil(n * p) + 1)
    # and each point lies on its triangle (barycentric coordinates in [0, 1])
    a, b, c = tri[pick, 0], tri[pick, 1], tri[pick, 2]
    M = np.stack([b - a, c - a], -1)
    uv = np.linalg.solve(np.einsum("kji,kjl->kil", M, M), np.einsum("kji,kj->ki", M, pts - a))
    assert uv.min() >= -1e-6 and uv.sum(1).max() <= 1 + 1e-6
    np.testing.assert_allclose(a + np.einsum("kij,kj->ki", M, uv), pts, atol=1e-9)


def _insert(s, centre_world, radius=0.3):
    c = s.world_to_camera(centre_world)
    b = sphere_object_bundle(s.camera, c, radius, (0.7, 0.7, 0.7), floor_normal=s.up_cam)
    d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
    ys, xs = np.nonzero(sel)
    mask = np.zeros(sel.shape, bool)
    h = ys.max() - ys.min()
    mask[max(0, ys.min() - h // 2):ys.max() + h, max(0, xs.min() - h):xs.max() + h] = True
    known = ~mask
    bg = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, known, s.camera, scene_key="k")
    comp = RenderRequest(SceneMaps(d, n, a), s.shading, known, s.camera, scene_key="k")
    return bg, comp, sel, mask


def test_cast_shadow_has_no_bands():
    s = floor_scene(160, 120, with_box=True, light_dir=SUN, ambient=0.3, box_center=(-0.4, -3.2))
    bg, comp, sel, mask = _insert(s, [0.4, 0.3, -2.6])
    out = PhysicalRenderer(shadow_softness=6.0).render([bg, comp], seed=1)
    ratio = out.images[1].mean(-1) / np.maximum(out.images[0].mean(-1), 1e-6)
    # the row through the lower part of the sphere's shadow, from the shadow's core
    # leftwards out into the light (the light comes from +x)
    ys, xs = np.nonzero(sel)
    y = int(ys.max() - (ys.max() - ys.min()) // 4)
    row = ratio[y, : xs.min()]
    core = int(np.argmin(row))
    left = row[: core + 1][::-1]  # from the core outwards
    left = left[mask[y, : core + 1][::-1]]
    assert left[0] < 0.6 and left.max() > 0.95
    ramp = left[: int(np.argmax(left > 0.95)) + 1]  # the penumbra: core -> lit
    assert len(ramp) >= 3
    assert np.all(np.diff(ramp) >= -0.01)  # monotonic up to noise well below a band


def test_mesh_shadow_from_posed_mesh(tmp_path):
    import trimesh

    from zcomp_cli.posed_mesh import load_posed_mesh
    from zcomp_cli.scene.objectshadow import mesh_shadow

    trimesh.creation.box(extents=(0.2, 1.0, 0.2)).export(tmp_path / "pole.glb")
    M = np.eye(4)
    M[:3, 3] = (0.0, -0.5, -3.0)  # a 1 m pole standing on y = -1, 3 m in front
    mesh = load_posed_mesh({"mesh": str(tmp_path / "pole.glb"), "object_to_camera": M.tolist()})
    assert mesh is not None and mesh.vertices[:, 1].min() == pytest.approx(-1.0)
    l = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)  # from the right, 45 deg up
    pts = np.array([[-0.5, -1.0, -3.0],   # left of the pole, inside its shadow
                    [0.5, -1.0, -3.0],    # right of it: lit
                    [-0.5, -1.0, -4.0]])  # left but behind: lit
    up = np.tile([0.0, 1.0, 0.0], (3, 1))
    vis, t = mesh_shadow(mesh, pts, up, l)
    assert vis.tolist() == [0.0, 1.0, 1.0]
    # along l the ray meets the pole after 0.4 * sqrt(2) m and leaves it after 0.6 * sqrt(2):
    # the shadow map keeps the far side (the highest surface toward the light)
    assert 0.4 * np.sqrt(2) - 0.05 <= t[0] <= 0.6 * np.sqrt(2) + 0.05
    # the pole does not shadow its own lit face
    face = np.array([[0.1, -0.5, -3.0]])
    assert mesh_shadow(mesh, face, np.array([[1.0, 0, 0]]), l)[0][0] == 1.0
    assert load_posed_mesh({}) is None


def _sphere_mesh(centre_cam, radius):
    import trimesh

    from zcomp_cli.posed_mesh import PosedMesh

    m = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    return PosedMesh(np.asarray(m.vertices) + np.asarray(centre_cam), np.asarray(m.faces))


def test_mesh_silhouette_covers_the_object_pixels():
    from zcomp_cli.scene.objectshadow import mesh_silhouette

    s = floor_scene(112, 84)
    c = s.world_to_camera([0.2, 0.15, -2.4])
    sil = mesh_silhouette(_sphere_mesh(c, 0.15), s.camera, s.depth.shape)
    b = sphere_object_bundle(s.camera, c, 0.15, floor_normal=s.up_cam)
    cover = b.mask > 0.5
    # every object pixel, and the silhouette's edge pixels at most one ring more
    assert (cover & ~sil).sum() <= 2
    assert sil.sum() < 1.25 * cover.sum()
    # behind the camera: nothing
    assert not mesh_silhouette(_sphere_mesh(-c, 0.15), s.camera, s.depth.shape).any()
    # wholly outside the frame: nothing
    assert not mesh_silhouette(_sphere_mesh(c + np.array([50.0, 0, 0]), 0.15), s.camera, s.depth.shape).any()
    # a non-finite vertex drops its triangles, nothing else
    bad = _sphere_mesh(c, 0.15)
    bad.vertices[0, 0] = np.nan
    sil_bad = mesh_silhouette(bad, s.camera, s.depth.shape)
    assert not (sil_bad & ~sil).any() and (sil & ~sil_bad).sum() <= 10


def test_a_dense_meshs_silhouette_is_the_object_and_one_ring_at_most():
    # 81920 faces over ~400 pixels: nearly every triangle lies within a 2x2 pixel block
    # (marked at once, not one fill each); the silhouette still covers the object and
    # reaches no further than the ring of its edge pixels
    import cv2
    import trimesh

    from zcomp_cli.scene.objectshadow import PosedMesh, mesh_silhouette

    s = floor_scene(112, 84)
    c = s.world_to_camera([0.2, 0.15, -2.4])
    sph = trimesh.creation.icosphere(subdivisions=6, radius=0.15)
    sil = mesh_silhouette(PosedMesh(np.asarray(sph.vertices) + c, np.asarray(sph.faces)), s.camera,
                          s.depth.shape)
    cover = sphere_object_bundle(s.camera, c, 0.15, floor_normal=s.up_cam).mask > 0.5
    assert (cover & ~sil).sum() <= 2
    ring = cv2.dilate(cover.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert not (sil & ~ring).any()


def test_a_thin_objects_shadow_comes_from_its_mesh_not_a_thick_depth_shell():
    """With the posed mesh, the floor behind a thin object's silhouette, which the real
    object leaves in the light, is not shadowed by the 2.5D depth marched with a
    guessed thickness (a dark line along the silhouette, a shadow too long)."""
    import dataclasses

    light = (-0.6, 0.5, -1.0)  # low, from behind-left: rays from the floor behind pass the object
    s = floor_scene(160, 120, light_dir=light, ambient=0.3)
    r = 0.08
    centre_w = np.array([0.0, r, -2.6])
    bg, comp, sel, mask = _insert(s, centre_w, radius=r)
    c = s.world_to_camera(centre_w)
    req = [bg, dataclasses.replace(comp, occluder=_sphere_mesh(c, r))]
    known = light_context({"direction": [float(v) for v in s.light_dir_cam], "angular_radius_deg": 0.5,
                           "strength": 2.0})
    out = PhysicalRenderer().render([dataclasses.replace(q, light=known) for q in req], seed=1)
    ratio = out.images[1].mean(-1) / np.maximum(out.images[0].mean(-1), 1e-6)
    # exact: the floor point's ray toward the light misses the sphere by a margin
    P = s.camera.unproject(s.depth).astype(np.float64)
    l = s.light_dir_cam / np.linalg.norm(s.light_dir_cam)
    rel = np.asarray(c) - P
    t = np.maximum(rel @ l, 0.0)
    miss = np.linalg.norm(rel - t[..., None] * l, axis=-1)
    lit = mask & ~sel & (s.depth > 0) & (miss > r + 0.04)
    shadowed = mask & ~sel & (s.depth > 0) & (miss < 0.7 * r)
    assert lit.sum() > 100 and shadowed.sum() > 10
    assert np.percentile(ratio[lit], 1) > 0.8  # lit stays lit (ambient occlusion aside)
    assert np.median(ratio[shadowed]) < 0.7  # the real shadow is drawn


def _uniform_sky_pool(n=4096):
    """``meshrays.sky_pool`` of a uniform sky over the hemisphere above +y."""
    from zcomp_cli import equirect
    from zcomp_cli.scene.meshrays import sky_pool
    from zcomp_cli.worldframe import ground_frame

    up = np.array([0.0, 1.0, 0.0])
    frame = ground_frame(up)
    d = equirect.pixel_directions(64, 128, frame)
    return sky_pool(np.ones((64, 128, 3)), d, equirect.solid_angles(64, 128), up, n)


def test_sky_occlusion_known_values():
    """The posed mesh's share of a point's cosine-weighted sky, by rays on the mesh: a
    sphere wholly above a floor point hides (r / d)^2 cos(theta) of it, by the contact
    too (where a few area elements read it lighter than a ring around it); faces turned
    away hide nothing; the winding does not matter; a mesh without area hides nothing."""
    from zcomp_cli.posed_mesh import PosedMesh
    from zcomp_cli.scene.meshrays import sky_occlusion

    r, c = 0.5, np.array([0.0, 0.5, 0.0])
    sph = _sphere_mesh(c, r)
    pool = _uniform_sky_pool()
    x = np.array([0.05, 0.1, 0.3, 0.7, 1.0, 1.5, 2.0])
    P = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    up = np.tile([0.0, 1.0, 0.0], (len(x), 1))
    dist = np.linalg.norm(c - P, axis=1)
    exact = (r / dist) ** 2 * (0.5 / dist)
    got = sky_occlusion(sph, P, up, pool, 4096, np.zeros(len(x)), np.full(len(x), 1e-4))[:, 0]
    assert np.allclose(got, exact, atol=0.02), (got, exact)
    inside_out = PosedMesh(sph.vertices, sph.faces[:, ::-1])
    assert np.allclose(sky_occlusion(inside_out, P, up, pool, 4096, np.zeros(len(x)), np.full(len(x), 1e-4)),
                       sky_occlusion(sph, P, up, pool, 4096, np.zeros(len(x)), np.full(len(x), 1e-4)))
    # a few rays a point, turned apart per pixel, average to the same
    few = [sky_occlusion(sph, P, up, pool, 32, np.full(len(x), (j + 0.5) / 16), np.full(len(x), 1e-4))[:, 0]
           for j in range(16)]
    assert np.allclose(np.mean(few, 0), exact, atol=0.02)
    # turned away from the sphere, or on top of it looking up: nothing hidden
    away = sky_occlusion(sph, np.array([[1.0, 0.5, 0.0], [0.0, 1.0 + 1e-3, 0.0]]),
                         np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), pool, 256, np.zeros(2), np.full(2, 1e-4))
    assert np.all(away < 1e-3)
    flat = PosedMesh(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    assert not sky_occlusion(flat, P, up, pool, 64, np.zeros(len(x)), np.zeros(len(x))).any()
    assert sky_occlusion(sph, np.zeros((0, 3)), np.zeros((0, 3)), pool, 8, np.zeros(0), np.zeros(0)).shape == (0, 3)


def test_sky_occlusion_is_each_channels_weighted_share_of_its_own_rays():
    """Against the definition, ray by ray: each point's k pool directions (its stratified
    share, turned by its jitter), each weighed by its cosine and its colour channel by
    channel; the hidden share the hit rays' weight over all of them. A sky coloured
    differently per direction, normals tilted every way, points near and under the
    sphere and far from it."""
    from zcomp_cli.scene.gather import caster
    from zcomp_cli.scene.meshrays import sky_occlusion

    sph = _sphere_mesh(np.array([0.0, 0.5, 0.0]), 0.5)
    rng = np.random.default_rng(4)
    dirs = rng.normal(size=(64, 3))
    dirs[:, 1] = np.abs(dirs[:, 1])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    chroma = rng.uniform(0.2, 1.5, size=(64, 3))
    chroma[::7, 0] = 0.0  # some directions without red: their green and blue are still hidden
    m = 200
    P = np.stack([rng.uniform(-1.5, 1.5, m), rng.uniform(0.0, 0.2, m), rng.uniform(-1.5, 1.5, m)], 1)
    N = rng.normal(size=(m, 3)) * [0.5, 1.0, 0.5] + [0.0, 1.0, 0.0]
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    jit, bias, k = rng.uniform(0, 1, m), np.full(m, 1e-4), 16
    got = sky_occlusion(sph, P, N, (dirs, chroma), k, jit, bias)
    start = P + N * bias[:, None]
    pick = ((jit * (64 / k)).astype(np.int64)[None] + (np.arange(k)[:, None] * 64) // k) % 64
    want = np.zeros((m, 3))
    rays = caster(sph)
    for i in range(m):
        d = dirs[pick[:, i]]
        w = np.maximum(d @ N[i], 0.0)[:, None] * chroma[pick[:, i]]
        hit = rays.occluded(np.repeat(start[i][None], k, 0), d)
        den = w.sum(0)
        want[i] = np.where(den > 1e-12, (w * hit[:, None]).sum(0) / np.maximum(den, 1e-300), 0.0)
    assert 0.1 < (got[:, 1] > 0).mean() < 0.9  # the points tell hidden from open sky
    assert np.allclose(got, want, rtol=0, atol=1e-12)


def test_sky_occlusion_weighs_each_direction_by_the_sky_behind_it():
    """Directions are drawn where the sky is bright: an object on the bright side of a
    point hides more of its sky than on the dark side, by the radiance's own share."""
    from zcomp_cli import equirect
    from zcomp_cli.scene.meshrays import sky_occlusion, sky_pool
    from zcomp_cli.worldframe import ground_frame

    r, c = 0.5, np.array([0.0, 0.5, 0.0])
    sph = _sphere_mesh(c, r)
    up = np.array([0.0, 1.0, 0.0])
    d = equirect.pixel_directions(64, 128, ground_frame(up))
    bright = np.where(d[..., :1] < 0, 4.0, 1.0) * np.ones(3)  # brighter toward -x
    pool = sky_pool(bright, d, equirect.solid_angles(64, 128), up, 4096)
    P = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    n = np.tile(up, (2, 1))
    plain = sky_occlusion(sph, P, n, _uniform_sky_pool(), 4096, np.zeros(2), np.full(2, 1e-4))[:, 0]
    side = sky_occlusion(sph, P, n, pool, 4096, np.zeros(2), np.full(2, 1e-4))[:, 0]
    # seen from +x the sphere stands toward -x, in the bright half
    assert side[0] > 1.3 * plain[0] and side[1] < 0.8 * plain[1]
    # a coloured sky is hidden per channel
    tint = np.where(d[..., :1] < 0, [4.0, 1.0, 1.0], [1.0, 1.0, 1.0])
    rgb = sky_occlusion(sph, P[:1], n[:1], sky_pool(tint, d, equirect.solid_angles(64, 128), up, 4096), 4096,
                        np.zeros(1), np.full(1, 1e-4))[0]
    assert rgb[0] > 1.2 * rgb[1] and np.isclose(rgb[1], rgb[2], atol=1e-9)


def test_light_visibility_samples_the_lights_disc():
    """The share of a light's disc a point sees past the mesh: a sun's penumbra about the
    geometric shadow's edge, full shadow under a sphere for a small sun and a partial one
    under a lamp wider than the sphere, an umbra under the sphere where a wide panel lamp
    sits above it, and no ray cast where none can reach the mesh."""
    from zcomp_cli.scene.lightmodel import Lamp, Sun
    from zcomp_cli.scene.meshrays import light_visibility

    r, c = 0.3, np.array([0.0, 1.0, 0.0])
    sph = _sphere_mesh(c, r)
    x = np.array([0.0, 0.2, 0.3, 0.4, 1.0])
    P = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    up = np.tile([0.0, 1.0, 0.0], (len(x), 1))
    bias = np.full(len(x), 1e-4)
    jit = np.zeros(len(x))
    sun = Sun(direction=[0.0, 1.0, 0.0], radius_deg=3.0, irradiance=[1.0, 1.0, 1.0])
    v = light_visibility(sph, P, up, sun, 256, jit, bias)
    assert v[0] == 0.0 and v[-1] == 1.0
    # the penumbra: 1 m below the sphere's edge, +-tan(3 deg) * ~1 m wide
    assert 0.3 < v[2] < 0.7 and v[1] < 0.1 and v[3] > 0.9
    # a lamp 1 m above the sphere, wider than it: under its centre the sphere hides
    # part of its disc, not all
    lamp = Lamp(position=[0.0, 2.0, 0.0], radius_m=0.8, intensity=[1.0, 1.0, 1.0])
    vl = light_visibility(sph, P, up, lamp, 256, jit, bias)
    assert 0.05 < vl[0] < 0.95 and vl[-1] > vl[0]
    panel = Lamp(position=[0.0, 2.0, 0.0], radius_m=0.8, intensity=[1.0, 1.0, 1.0], facing=[0.0, -1.0, 0.0])
    vp = light_visibility(sph, P, up, panel, 256, jit, bias)
    assert np.isclose(vp[0], vl[0], atol=0.1)  # a panel facing down is the sphere's disc here
    # rays that cannot pass near the mesh are not cast: they see the whole light
    far = light_visibility(sph, np.array([[5.0, 0.0, 0.0]]), up[:1], sun, 16, np.zeros(1), np.full(1, 1e-4))
    assert far[0] == 1.0


def test_the_sky_a_floating_object_hides_comes_from_its_mesh():
    """On a bare floor (contact shadow: the expected shadow is the ambient occlusion),
    the floor around a sphere floating above it is darkened by what the real sphere
    hides of the sky, not by its 2.5D shell marched as a solid slab: the floor seen just
    past its silhouette is no darker than the mesh's occlusion allows, and the floor
    under it is darkened."""
    import dataclasses

    s = floor_scene(160, 120, light_dir=SUN, ambient=0.3)
    r = 0.15
    centre_w = np.array([0.1, 0.3, -2.5])  # 0.15 m above the floor
    bg, comp, sel, mask = _insert(s, centre_w, radius=r)
    c = s.world_to_camera(centre_w)
    out = PhysicalRenderer().render([bg, dataclasses.replace(comp, occluder=_sphere_mesh(c, r))], seed=1)
    assert out.info["fallback"]
    ratio = out.images[1].mean(-1) / np.maximum(out.images[0].mean(-1), 1e-6)
    P = s.camera.unproject(s.depth).astype(np.float64)
    rel = np.asarray(c) - P
    dist = np.linalg.norm(rel, axis=-1)
    occ = (r / dist) ** 2 * np.clip((rel @ s.up_cam) / dist, 0.0, 1.0)
    floor = mask & ~sel & (s.depth > 0)
    assert (floor & (occ > 0.1)).sum() > 20
    # never much darker than the real occlusion (the slab made it 0.27 of the sky
    # under a chair's seat where the mesh hides 0.3-0.4)
    assert np.percentile((1.0 - ratio[floor]) - occ[floor], 99) < 0.08
    # the darkening is there where the sphere hides much of the sky
    deep = floor & (occ > 0.12)
    assert deep.sum() > 5 and np.median(ratio[deep]) < 1.0 - 0.3 * np.median(occ[deep])
    # it fades out toward the shading mask's edge (cut there, it drew an ellipse)
    import cv2

    edge = floor & ~(cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    assert (occ[edge] > 0.02).any() and np.abs(ratio[edge] - 1.0).max() < 0.01


@pytest.mark.parametrize("shape", ["box", "capsule"])
def test_mesh_silhouette_has_no_holes_where_faces_overlap(shape):
    """A closed mesh's front and back faces overlap on screen: each triangle is filled on
    its own, not by the even-odd rule over all of them (which left holes, and the
    object's pixels outside the silhouette occluded the march: a speckled shadow)."""
    import cv2
    import trimesh

    from zcomp_cli.scene.objectshadow import PosedMesh, mesh_silhouette

    s = floor_scene(112, 84)
    m = trimesh.creation.box((0.3, 0.4, 0.25)) if shape == "box" else trimesh.creation.capsule(0.35, 0.15)
    rot = trimesh.transformations.rotation_matrix(0.6, [1, 1, 0])[:3, :3]
    V = np.asarray(m.vertices) @ rot.T + s.world_to_camera([0.1, 0.4, -2.4])
    sil = mesh_silhouette(PosedMesh(V, np.asarray(m.faces)), s.camera, s.depth.shape)
    xy, _ = s.camera.project(V)
    hull = np.zeros(s.depth.shape, np.uint8)
    cv2.fillConvexPoly(hull, cv2.convexHull(np.round(xy - 0.5).astype(np.int32)), 1)
    inner = cv2.erode(hull, np.ones((3, 3), np.uint8)) > 0  # a convex shape: its hull
    assert inner.sum() > 200 and not (inner & ~sil).any()


def test_a_degenerate_or_non_finite_occluder_mesh_hides_nothing_and_stays_finite():
    """A posed mesh without area (all its triangles collapsed) or with a non-finite
    vertex: the composite stays finite, and the collapsed one changes nothing."""
    import dataclasses

    from zcomp_cli.posed_mesh import PosedMesh

    s = floor_scene(112, 84, light_dir=SUN, ambient=0.3)
    bg, comp, sel, mask = _insert(s, [0.0, 0.3, -2.6])
    c = s.world_to_camera([0.0, 0.3, -2.6])
    flat = PosedMesh(np.repeat(np.asarray(c, np.float64)[None], 3, 0), np.array([[0, 1, 2]]))
    bad = _sphere_mesh(c, 0.3)
    bad.vertices[0] = np.nan
    base = PhysicalRenderer().render([bg, comp], seed=1).images[1]
    known = light_context({"direction": [float(v) for v in s.light_dir_cam], "angular_radius_deg": 2.0,
                           "strength": 2.0})
    for occ in (flat, bad):
        img = PhysicalRenderer().render([bg, dataclasses.replace(comp, occluder=occ)], seed=1).images[1]
        assert np.all(np.isfinite(img))
        # with a light to cast its shadow too (the shadow map sampled it: a ValueError)
        req = [dataclasses.replace(q, light=known) for q in (bg, dataclasses.replace(comp, occluder=occ))]
        assert np.all(np.isfinite(PhysicalRenderer().render(req, seed=1).images[1]))
    img = PhysicalRenderer().render([bg, dataclasses.replace(comp, occluder=flat)], seed=1).images[1]
    assert np.array_equal(img, base)  # as if there were none


def test_a_meshs_triangle_areas_are_kept_for_its_arrays_only():
    # kept on the mesh for its uses in one render, read-only; new vertex arrays (a new
    # pose) are measured again
    from zcomp_cli.posed_mesh import PosedMesh
    from zcomp_cli.scene.objectshadow import area_triangles as _area_triangles

    mesh = PosedMesh(np.array([[0.0, 0, -3], [1, 0, -3], [0, 1, -3], [0, 0, -4]]), np.array([[0, 1, 2], [0, 1, 3]]))
    tri, cr, area, _ = _area_triangles(mesh)
    assert _area_triangles(mesh)[2] is area
    np.testing.assert_allclose(area, [0.5, 0.5])
    with pytest.raises(ValueError):
        area[0] = 2.0
    mesh.vertices = mesh.vertices * 2.0
    np.testing.assert_allclose(_area_triangles(mesh)[2], [2.0, 2.0])


def test_a_dark_objects_contact_is_darker_than_a_light_ones():
    """The sky the object's mesh hides from the floor still brings what the object
    bounces, at the object's own albedo (the scene's occluders at the scene's): a dark
    vase's contact is darker than a white one's by about the share it hides times the
    bounce's difference (``TransportConfig.sky_bounce``), where both were drawn alike."""
    import dataclasses

    from zcomp_cli.renderers.physical.settings import TransportConfig

    s = floor_scene(160, 120, light_dir=SUN, ambient=0.3)
    r = 0.2
    centre_w = np.array([0.1, r, -2.5])  # resting on the floor
    c = s.world_to_camera(centre_w)
    P = s.camera.unproject(s.depth).astype(np.float64)
    rel = np.asarray(c) - P
    dist = np.linalg.norm(rel, axis=-1)
    occ = (r / dist) ** 2 * np.clip((rel @ s.up_cam) / dist, 0.0, 1.0)
    ratios = {}
    for grey in (0.05, 0.9):
        b = sphere_object_bundle(s.camera, c, r, (grey, grey, grey), floor_normal=s.up_cam)
        d, n, a, sel = insert_bundle(s.depth, s.normals, s.albedo, b)
        ys, xs = np.nonzero(sel)
        mask = np.zeros(sel.shape, bool)
        h = ys.max() - ys.min()
        mask[max(0, ys.min() - h // 2):ys.max() + h, max(0, xs.min() - h):xs.max() + h] = True
        bg = RenderRequest(SceneMaps(s.depth, s.normals, s.albedo), s.shading, ~mask, s.camera, scene_key="k")
        comp = RenderRequest(SceneMaps(d, n, a), s.shading, ~mask, s.camera, scene_key="k",
                             coverage=sel.astype(np.float64), occluder=_sphere_mesh(c, r))
        out = PhysicalRenderer().render([bg, comp], seed=1)
        ratios[grey] = out.images[1].mean(-1) / np.maximum(out.images[0].mean(-1), 1e-6)
        floor = mask & ~sel & (s.depth > 0)
    near = floor & (occ > 0.15)
    assert near.sum() > 10
    gap = ratios[0.9][near] - ratios[0.05][near]
    assert np.all(gap >= -1e-6)
    # the hidden share (about occ of the sky, the floor's ambient share of its light)
    # bounces (0.9 - 0.05) x sky_bounce more off the white ball
    assert np.median(gap) > 0.25 * TransportConfig().sky_bounce * 0.85 * np.median(occ[near])
    far = floor & (occ < 0.01)
    assert np.abs(ratios[0.9][far] - ratios[0.05][far]).max() < 0.01


def test_a_probes_window_shades_a_ball_from_the_pool_as_it_is():
    """``meshrays.pool_shading``: a sky of a dim dome and one bright window 30 degrees up
    shades normals around the horizon as the exact integral over the map does (within
    1 %), where its order-2 SH is 16 % off (too bright on the dark side, too dark at the
    window's edge)."""
    from zcomp_cli import equirect
    from zcomp_cli.scene import sh
    from zcomp_cli.scene.meshrays import pool_shading, sky_pool
    from zcomp_cli.worldframe import ground_frame

    up = np.array([0.0, 1.0, 0.0])
    h, w = 64, 128
    d = equirect.pixel_directions(h, w, ground_frame(up))
    om = equirect.solid_angles(h, w)
    win = np.array([0.8, 0.5, 0.0]) / np.linalg.norm([0.8, 0.5, 0.0])
    L = (0.3 + 20.0 * np.exp(-(1.0 - d @ win) / 0.02))[..., None] * np.array([1.0, 0.9, 0.7])
    L = L * ((d @ up) > 0)[..., None]
    c = sh.project(d.reshape(-1, 3), L.reshape(-1, 3), om.reshape(-1))
    ang = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)
    n = np.stack([np.cos(ang), np.full_like(ang, 0.3), np.sin(ang)], 1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    exact = (np.maximum(n @ d.reshape(-1, 3).T, 0.0) * om.reshape(-1)) @ L.reshape(-1, 3) / np.pi
    got = pool_shading(sky_pool(L, d, om, up, 512), c, n)
    smooth = np.maximum(sh.evaluate(sh.shading_coeffs(c), n), 0.0)
    assert np.max(np.abs(got - exact) / exact) < 0.01
    assert np.max(np.abs(smooth - exact) / exact) > 0.1
    # an empty pool (a black sky) falls back to the SH's own shading
    assert np.allclose(pool_shading((np.zeros((0, 3)), np.zeros((0, 3))), c, n), smooth)
