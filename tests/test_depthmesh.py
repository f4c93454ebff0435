"""The photograph's geometry as a triangle mesh (renderers/physical/depthmesh.py): on
analytic floor scenes (zcomp_cli.testing) the support, the occluders and casters, the
discontinuities cut, and the ray-cast shadow of the extruded mesh against the scene's
exact one."""

import numpy as np
import pytest

from zcomp_cli.scene.depthmesh import DepthMesh, build_depth_mesh
from zcomp_cli.scene.raycast import RayCaster
from zcomp_cli.scene.frame import scene_up
from zcomp_cli.light.config import DEFAULT_LIGHT
from zcomp_cli.testing import floor_scene

W, H = 160, 120
BOX = dict(box_center=(-0.3, -3.2), box_size=(0.6, 0.8, 0.6))
# box_albedo is (0.5, 0.4, 0.3), the floor's (0.6, 0.6, 0.6): the box's pixels by albedo
BOX_BLUE = 0.35


def _mesh(s, **kw) -> tuple[DepthMesh, np.ndarray]:
    up, _ = scene_up(None, s.normals, s.depth > 0)
    return build_depth_mesh(s.depth, s.normals, s.camera, up, **kw), up


def _box_pixels(s) -> np.ndarray:
    return (s.depth > 0) & (s.albedo[..., 2] < BOX_BLUE)


def _iou(a, b) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def _support_shadow(m: DepthMesh, caster: RayCaster, light) -> np.ndarray:
    """(h, w) the support pixels whose biased ray toward ``light`` is occluded."""
    P = m.points[m.support]
    O = P + m.up[None] * (DEFAULT_LIGHT.search.bias_rel * np.maximum(-P[:, 2], 1e-6))[:, None]
    out = np.zeros(m.shape, bool)
    out[m.support] = caster.occluded(O, light)
    return out


def _shell_caster(m: DepthMesh) -> RayCaster:
    """The front shell alone: the faces among the pixels' own vertices (indices < h w),
    less the support's (as ``DepthMesh.caster``)."""
    h, w = m.shape
    front = m.faces[np.all(m.faces < h * w, axis=1)]
    front = front[~np.all(m.support.ravel()[front], axis=1)]
    return RayCaster(m.vertices, front)


def test_shapes_and_vertex_layout():
    s = floor_scene(W, H, with_box=True, **BOX)
    m, up = _mesh(s)
    h, w = m.shape
    assert (h, w) == (H, W) and m.points.shape == (H, W, 3)
    for a in (m.valid, m.support, m.occluder, m.base, m.casters):
        assert a.shape == (H, W) and a.dtype == bool
    assert m.labels.shape == (H, W) and np.issubdtype(m.labels.dtype, np.integer)
    assert m.faces.ndim == 2 and m.faces.shape[1] == 3 and m.faces.min() >= 0 and m.faces.max() < len(m.vertices)
    # the first h w vertices are the pixels' points, the rest the occluders' back copies
    np.testing.assert_allclose(m.vertices[:h * w], m.points.reshape(-1, 3))
    assert len(m.vertices) == 2 * h * w
    np.testing.assert_allclose(np.linalg.norm(m.up), 1.0)
    # the support and the occluders partition the valid pixels
    assert not (m.support & m.occluder).any() and ((m.support | m.occluder) == m.valid).all()
    assert ((m.labels > 0) == m.occluder).all()
    assert not (m.base & ~m.occluder).any() and not (m.casters & ~m.occluder).any()
    # the support's height: the floor, camera_height (1.2 m) below the camera
    assert abs(m.support_height - (-1.2)) < 0.01


def test_the_support_is_the_floor_and_the_box_one_caster():
    s = floor_scene(W, H, with_box=True, **BOX)
    m, up = _mesh(s)
    box = _box_pixels(s)
    floor = (s.depth > 0) & ~box
    top = box & (s.normals @ up > 0.9)
    assert top.sum() > 50  # the box's top is seen (and faces up like the floor)
    assert m.support[floor].mean() > 0.98
    assert not m.support[box].any() and not m.support[top].any()
    assert m.occluder[box].all() and m.occluder.sum() == box.sum()
    # one occluder component, standing on the floor, showing a silhouette: a caster
    assert len(np.unique(m.labels[box])) == 1 and m.labels.max() == 1
    assert m.base[box].sum() > 10 and m.casters[box].all() and not m.casters[~box].any()
    # the base is the box's bottom: its pixels low in the box (next to the floor)
    P = m.points[m.base]
    assert np.all(P @ up - m.support_height < 0.1)


@pytest.mark.parametrize("size, centre", [((0.6, 0.5, 0.6), (0.3, -3.0)), ((0.45, 0.76, 0.45), (0.03, -3.49)),
                                          ((0.7, 0.65, 0.7), (0.04, -3.01))])
def test_a_box_is_one_occluder_component(size, centre):
    s = floor_scene(W, H, with_box=True, box_center=centre, box_size=size)
    m, up = _mesh(s)
    box = _box_pixels(s)
    assert (box & (s.normals @ up > 0.9)).sum() > 30  # its top is seen
    assert len(np.unique(m.labels[box])) == 1 and m.casters[box].all()


def test_a_box_whose_crease_falls_badly_is_one_occluder_component():
    """The top and the front of a box meet at a convex crease seen at a grazing angle:
    one occluder (a side seen edge on, a one-pixel column of one depth, may stand apart:
    it stands on the support too)."""
    s = floor_scene(W, H, with_box=True, box_center=(-0.3, -3.2), box_size=(0.5, 0.6, 0.5))
    m, up = _mesh(s)
    box = _box_pixels(s)
    top = box & (s.normals @ up > 0.9)
    assert top.sum() > 30
    labels, counts = np.unique(m.labels[box], return_counts=True)
    main = labels[np.argmax(counts)]
    assert (m.labels[top] == main).all() and counts.max() > 0.95 * box.sum() and m.casters[box].all()


def test_a_wall_is_no_caster():
    s = floor_scene(W, H, with_wall=True, pitch_deg=-10.0)
    m, up = _mesh(s)
    wall = (s.depth > 0) & (np.abs(s.normals @ up) < 0.2)
    assert wall.sum() > 1000
    assert m.occluder[wall].mean() > 0.98  # the wall is an occluder...
    assert not m.casters.any()  # ...that casts nothing the photograph's shadows are read from
    # with a box before it, the box is the only caster
    s2 = floor_scene(W, H, with_wall=True, pitch_deg=-10.0, with_box=True, **BOX)
    m2, _ = _mesh(s2)
    box = _box_pixels(s2)
    assert m2.casters[box].mean() > 0.95 and not m2.casters[~box].any()


@pytest.mark.parametrize("light", [(0.7, 1.0, 0.2), (-0.6, 0.8, 0.3), (0.5, 0.7, 0.6), (0.3, 1.0, -0.5)])
def test_the_meshs_shadow_matches_the_exact_one(light):
    s = floor_scene(W, H, with_box=True, light_dir=light, **BOX)
    m, up = _mesh(s)
    box = _box_pixels(s)
    ys, xs = np.nonzero(box)
    assert ys.min() > 0 and xs.min() > 0 and xs.max() < W - 1  # the box, top included, is in the frame
    true = m.support & (s.visibility < 0.5)
    assert true.sum() > 150
    light_cam = s.light_dir_cam
    ext = _support_shadow(m, m.caster(), light_cam)
    shell = _support_shadow(m, _shell_caster(m), light_cam)
    iou_ext, iou_shell = _iou(ext, true), _iou(shell, true)
    assert iou_ext > 0.7
    # a thin shell lets rays pass behind the visible surface: the extrusion fills it
    assert iou_ext > iou_shell
    # the light from the other side of the sky throws the shadow elsewhere
    away = 2 * (light_cam @ up) * up - light_cam  # the same elevation, the opposite azimuth
    assert _iou(_support_shadow(m, m.caster(), away), true) < 0.2


def test_the_support_casts_no_shadow_on_itself():
    s = floor_scene(W, H)  # a bare floor
    m, up = _mesh(s)
    assert m.support.mean() > 0.5 and not m.occluder.any() and not m.casters.any()
    assert m.caster().backend == "none"
    for light in (up, 0.3 * up + np.array([1.0, 0.0, 0.0])):
        assert not _support_shadow(m, m.caster(), light / np.linalg.norm(light)).any()


def test_holes_do_not_raise_and_vertices_are_finite():
    s = floor_scene(W, H, with_box=True, **BOX)
    d = s.depth.copy()
    rng = np.random.default_rng(0)
    d[rng.random(d.shape) < 0.03] = np.nan
    d[rng.random(d.shape) < 0.03] = np.inf
    d[rng.random(d.shape) < 0.03] = 0.0
    d[rng.random(d.shape) < 0.01] = -1.0
    d[40:50, 50:70] = np.nan  # a hole through the box
    n = s.normals.copy()
    n[rng.random(d.shape) < 0.02] = np.nan
    up, _ = scene_up(None, s.normals, s.depth > 0)
    m = build_depth_mesh(d, n, s.camera, up)
    bad = ~np.isfinite(d) | (d <= 0) | ~np.all(np.isfinite(n), -1)
    assert not m.valid[bad].any() and m.valid[~bad & (s.depth > 0)].all()
    assert np.all(np.isfinite(m.points[m.valid]))
    used = np.unique(m.faces)
    assert len(used) and np.all(np.isfinite(m.vertices[used]))
    assert m.support.sum() > 0.8 * (m.valid & ~_box_pixels(s)).sum()
    rc = m.caster()
    assert rc.n_faces > 0
    # all-invalid maps: nothing, and no error
    e = build_depth_mesh(np.full(d.shape, np.nan), n, s.camera, up)
    assert not e.valid.any() and not e.support.any() and len(e.faces) == 0 and e.caster().backend == "none"


def _spanning_pairs(m: DepthMesh, a: np.ndarray, b: np.ndarray, ratio: float):
    """The triangle edges joining a pixel of ``a`` to a pixel of ``b`` more than ``ratio``
    times deeper: (pixel of a, pixel of b) flat indices."""
    h, w = m.shape
    F = m.faces[np.all(m.faces < h * w, axis=1)]
    z = -m.points.reshape(-1, 3)[:, 2]
    af, bf = a.ravel(), b.ravel()
    out = []
    for i, j in ((0, 1), (1, 2), (0, 2)):
        for p, q in ((F[:, i], F[:, j]), (F[:, j], F[:, i])):
            sel = af[p] & bf[q] & (z[q] > ratio * z[p])
            out.append(np.stack([p[sel], q[sel]], 1))
    return np.concatenate(out)


def test_the_box_top_edge_against_the_floor_behind_is_cut():
    s = floor_scene(W, H, with_box=True, **BOX)
    m, up = _mesh(s)
    h, w = m.shape
    box = _box_pixels(s)
    floor = (s.depth > 0) & ~box
    # the box's top outline: a box pixel right below a floor pixel seen much farther
    above = np.zeros_like(box)
    above[1:] = box[1:] & floor[:-1] & (s.depth[:-1] > 1.05 * s.depth[1:])
    assert above.sum() > 20
    pairs = _spanning_pairs(m, box, floor, 1.05)
    vertical = pairs[(pairs[:, 1] == pairs[:, 0] - w)]
    assert len(vertical) == 0
    # the box's silhouette is a depth discontinuity: it is a caster, the floor whole
    assert m.casters[above].all()
    # the floor far from the box stays whole: its pixels are corners of triangles
    used = np.zeros(h * w, bool)
    used[m.faces[np.all(m.faces < h * w, axis=1)].ravel()] = True
    assert used.reshape(h, w)[m.support].mean() > 0.97


def test_no_triangle_spans_the_boxs_side_silhouette():
    s = floor_scene(W, H, with_box=True, box_center=(-0.3, -3.2), box_size=(0.5, 0.6, 0.5))
    m, up = _mesh(s)
    box = _box_pixels(s)
    floor = (s.depth > 0) & ~box
    assert len(_spanning_pairs(m, box, floor, 1.1)) == 0


def test_the_shadow_of_a_box_seen_near_its_side_edge():
    s = floor_scene(W, H, with_box=True, box_center=(-0.3, -3.2), box_size=(0.5, 0.6, 0.5),
                    light_dir=(-0.7, 0.8, -0.1))
    m, up = _mesh(s)
    ys, xs = np.nonzero(_box_pixels(s))
    assert ys.min() > 0 and xs.min() > 0 and xs.max() < W - 1
    true = m.support & (s.visibility < 0.5)
    assert true.sum() > 150
    assert _iou(_support_shadow(m, m.caster(), s.light_dir_cam), true) > 0.7


def test_walls_beyond_the_frame_join_as_quads():
    from zcomp_cli.scene.planes import Wall

    s = floor_scene(W, H)
    m0, up = _mesh(s)
    # a wall 2 m to the camera's left (camera frame; its normal toward the camera's side)
    right = np.cross(np.array([0.0, 0.0, -1.0]), up)
    right /= np.linalg.norm(right)
    wall = Wall(normal=right, offset=-2.0, top=3.0, ground=m0.support_height, up=up)
    m = build_depth_mesh(s.depth, s.normals, s.camera, up, walls=(wall,))
    assert len(m.faces) == len(m0.faces) + 2 and len(m.vertices) == len(m0.vertices) + 4
    P = m.points[m.support]
    P = P[(P @ right > -1.8) & (P @ right < 1.0)]  # the floor on the camera's side of the wall
    assert len(P) > 1000
    O = P + up[None] * 0.01
    rc = m.caster()
    # toward the wall, low: blocked; away from it, or above its top: not
    low_left = -right + 0.2 * up
    assert rc.occluded(O, low_left / np.linalg.norm(low_left)).mean() > 0.95
    assert not rc.occluded(O, right).any()
    assert not rc.occluded(O, up).any()


# a wall 1.5 m high across the frame, 5 m ahead: the camera (1.2 m up, pitched down 10 deg)
# sees its top edge against the sky
TOPPED_WALL = [((0.0, -5.0), (30.0, 1.5, 0.3))]


def test_a_wall_whose_top_edge_is_seen_is_a_caster_where_sky_edges_cast():
    # a wall meets the floor in a corner: where its top edge stands against the sky
    # (pixels of no geometry above it), that edge casts its shadow on the floor. With
    # ``sky_edges_cast`` the wall is a caster; a wall the frame cuts at its top stays none;
    # by default (off: design notes) no wall is
    from zcomp_cli.scene.config import MeshConfig

    on = MeshConfig(sky_edges_cast=True)
    s = floor_scene(W, H, pitch_deg=-10.0, occluders=TOPPED_WALL)
    m, up = _mesh(s, cfg=on)
    wall = (s.depth > 0) & (np.abs(s.normals @ up) < 0.2)
    assert wall.sum() > 1000 and (s.depth[0] == 0).all()  # the sky above it
    assert m.casters[wall].mean() > 0.98 and not m.casters[~wall].any()
    assert not _mesh(s)[0].casters.any()
    cut = floor_scene(W, H, pitch_deg=-25.0, occluders=TOPPED_WALL)
    assert (cut.depth[0] > 0).all()  # the frame's top cuts the wall
    assert not _mesh(cut, cfg=on)[0].casters.any()
