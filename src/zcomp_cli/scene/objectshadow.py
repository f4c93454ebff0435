"""The inserted object's shadow from its real posed mesh: a shadow map per light.

The 2.5D composite depth has no back side: a thin object's shadow is cut where rays
pass "behind" its visible shell. With the object bundle's mesh and pose (``meta.json``:
``mesh``, ``object_to_camera``), a shadow map is made from the light: surface samples of
the posed mesh (area-weighted) are splatted into an orthographic grid perpendicular to
the light (``mesh_shadow``; a lamp's is a perspective one, ``mesh_shadow_point``),
keeping per cell the height toward the light; a small max filter closes the gaps
between samples. A point is in the object's shadow when a cell it projects to holds a
surface higher (toward the light) than the point by more than a bias; the difference is
the occluder distance the penumbra filter needs. ``mesh_silhouette`` is the mesh's
coverage of the image.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.posed_mesh import PosedMesh
from zcomp_cli.scene.config import ObjectShadowConfig
from zcomp_cli.scene.sampling import orthonormal


def area_triangles(mesh: PosedMesh):
    """The mesh's triangles with area (finite corners, non-zero area) as the sky's
    elements and its exact near field both use them: (tri (M, 3, 3), corner cross
    products (M, 3), areas (M,), inside_out). ``inside_out``: wound inside out, a
    negative signed volume; their outward normals are then the cross products turned.

    Kept on the mesh for its other uses in the same render (its shadow map per light,
    its sky elements, its near field: four a job), while it holds the same vertex and
    face arrays (a posed mesh's arrays are not changed in place)."""
    memo = getattr(mesh, "_area_memo", None)
    if memo is not None and memo[0] is mesh.vertices and memo[1] is mesh.faces:
        return memo[2]
    tri = mesh.vertices[mesh.faces]
    with np.errstate(invalid="ignore"):  # a non-finite corner: dropped just below
        cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area = 0.5 * np.linalg.norm(cr, axis=1)
    ok = area > 0  # (False for a non-finite corner too)
    tri, cr, area = tri[ok], cr[ok], area[ok]
    inside_out = bool(len(tri)) and bool(np.einsum("ij,ij->i", tri[:, 0] - tri[:, 0].mean(0), cr).sum() < 0)
    for a in (tri, cr, area):
        a.setflags(write=False)  # shared by the mesh's uses
    out = (tri, cr, area, inside_out)
    try:
        mesh._area_memo = (mesh.vertices, mesh.faces, out)
    except AttributeError:  # (a mesh type without a __dict__: computed each time)
        pass
    return out


def mesh_silhouette(mesh: PosedMesh, camera, shape) -> np.ndarray:
    """(H, W) bool: the pixels the posed mesh covers in ``camera``'s image (its
    triangles rasterised, edge pixels included; those reaching behind the camera are
    left out).

    Where the mesh is known it alone stands for the object as an occluder: the 2.5D
    depth's shell, marched with a guessed thickness, shadows floor pixels just behind a
    thin object's silhouette (a dark one-pixel line along it) and lengthens its shadow."""
    import cv2

    H, W = shape
    out = np.zeros((H, W), np.uint8)
    xy, z = camera.project(mesh.vertices)
    tri = mesh.faces[np.all(z[mesh.faces] > 1e-6, axis=1)]
    if len(tri) == 0:
        return out > 0
    q = xy[tri]  # (M, 3, 2) pixels
    # drop triangles wholly outside the frame, and non-finite or absurd projections
    # (checked before the integer cast, which would wrap them)
    keep = np.all(np.isfinite(q) & (np.abs(q) < 2 ** 22), axis=(1, 2))
    lo, hi = q.min(1), q.max(1)
    keep &= (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & (lo[:, 0] < W) & (lo[:, 1] < H)
    q, lo, hi = q[keep], lo[keep], hi[keep]
    # A triangle within a 2x2 block of pixels (most of a dense mesh's, seen from afar)
    # covers some of them: all four are marked, at once (a pixel index i spans
    # [i, i + 1)); one cv2 call per triangle cost 0.5 s for a 330k-face mesh. This
    # widens the silhouette by at most the pixel its edge passes through.
    i0 = np.floor(lo).astype(np.int64)
    i1 = np.floor(hi).astype(np.int64)
    small = np.all(i1 - i0 <= 1, axis=1)
    for dy in (0, 1):
        for dx in (0, 1):
            y = np.where(dy, i1[small, 1], i0[small, 1])
            x = np.where(dx, i1[small, 0], i0[small, 0])
            ok = (x >= 0) & (x < W) & (y >= 0) & (y < H)
            out[y[ok], x[ok]] = 1
    pts = np.round(q[~small] * 16.0).astype(np.int32)  # 4 fractional bits
    # a pixel index i spans [i, i + 1): shift by half a pixel so cv2 fills by centres.
    # One triangle per call: ``fillPoly`` given them all fills by the even-odd rule, so
    # a closed mesh's front and back faces cancelled (330 of a capsule's 2463 pixels
    # left out, and those occluded the march with a speckled shadow)
    for t in pts - 8:
        cv2.fillConvexPoly(out, t, 1, lineType=cv2.LINE_8, shift=4)
    return out > 0


def sample_triangles(tri: np.ndarray, p: np.ndarray, n: int):
    """``n`` points uniform over triangles ``tri`` (M, 3, 3), each picked with
    probability ``p`` (M,) (its share of the area, stratified): (picked triangle indices (n,),
    points (n, 3)). Deterministic (seed 0), so a mesh always gives the same samples."""
    rng = np.random.default_rng(0)
    # stratified picks (one jittered uniform in each of n equal strata of the area's
    # CDF): each triangle gets the floor or ceiling of its expected count, so the
    # samples cover the surface evenly instead of in Poisson clumps and gaps (a shadow
    # map needs a sample in every few cells); sorted, they also look the CDF up in order
    cdf = np.cumsum(p)
    pick = np.minimum(np.searchsorted(cdf / cdf[-1], (np.arange(n) + rng.random(n)) / n, side="right"),
                      len(tri) - 1)
    r1, r2 = rng.random(n), rng.random(n)
    s1 = np.sqrt(r1)
    # (the picked triangles' corners in one gather of contiguous rows: tri[pick, k]
    # three times cost more than the rest)
    g = np.take(np.ascontiguousarray(tri).reshape(-1, 9), pick, axis=0)
    pts = g[:, 0:3] * (1 - s1)[:, None]
    pts += g[:, 3:6] * (s1 * (1 - r2))[:, None]
    pts += g[:, 6:9] * (s1 * r2)[:, None]
    return pick, pts


def _splat(su, sv, sh, cell):
    """Max-splat samples (u, v, height toward the light) into a grid of ``cell``, the
    gaps between samples closed by a 3x3 max filter: (grid (H, W), u0, v0)."""
    from scipy.ndimage import maximum_filter

    u0, v0 = su.min() - 2 * cell, sv.min() - 2 * cell
    W = int(np.ceil((su.max() - u0) / cell)) + 3
    H = int(np.ceil((sv.max() - v0) / cell)) + 3
    grid = np.full((H, W), -np.inf)
    iu = np.clip(((su - u0) / cell).astype(np.int64), 0, W - 1)
    iv = np.clip(((sv - v0) / cell).astype(np.int64), 0, H - 1)
    np.maximum.at(grid, (iv, iu), sh)
    return maximum_filter(grid, size=3, mode="constant", cval=-np.inf), u0, v0


def _lookup(grid, u0, v0, cell, pu, pv):
    H, W = grid.shape
    ju = np.floor((pu - u0) / cell).astype(np.int64)
    jv = np.floor((pv - v0) / cell).astype(np.int64)
    inside = (ju >= 0) & (ju < W) & (jv >= 0) & (jv < H)
    out = np.full(len(pu), -np.inf)
    out[inside] = grid[jv[inside], ju[inside]]
    return out


def _samples(mesh: PosedMesh, ext: float, cell: float, cfg: ObjectShadowConfig):
    tri, _, area, _ = area_triangles(mesh)
    n_s = int(min(cfg.mesh_max_samples, max(2000, cfg.mesh_sample_density * area.sum() / cell ** 2)))
    return sample_triangles(tri, area / max(area.sum(), 1e-12), n_s)[1]


def mesh_shadow(mesh: PosedMesh, points: np.ndarray, normals: np.ndarray, light_dir, *,
                bias_rel: float | None = None, cfg: ObjectShadowConfig | None = None, cell: float | None = None):
    """Visibility of camera-frame ``points`` (N, 3) toward ``light_dir`` past the mesh
    (``cell`` None: the extent over ``cfg.mesh_shadow_cells``; ``bias_rel`` the bias's
    share of the point's depth, ``MarchConfig.march_bias_rel``; each None: the
    defaults).

    Returns:
        (vis (N,) in {0, 1}, t_hit (N,) distance to the occluder, inf where lit).
    """
    cfg, bias_rel = _defaults(cfg, bias_rel)
    l = np.asarray(light_dir, np.float64)
    l = l / np.linalg.norm(l)
    u, v = orthonormal(l)
    # a non-finite corner drops its triangle (as the silhouette and the sky's elements
    # do); a mesh left without area shadows nothing (sampling it raised a ValueError)
    _, _, area, _ = area_triangles(mesh)
    P = np.asarray(points, np.float64)
    if not area.sum() > 0:
        return np.ones(len(P)), np.full(len(P), np.inf)
    V = mesh.vertices[np.all(np.isfinite(mesh.vertices), axis=1)]
    ext = np.ptp(V @ np.stack([u, v], 1), axis=0).max() + 1e-9
    if cell is None:
        cell = ext / cfg.mesh_shadow_cells
    smp = _samples(mesh, ext, cell, cfg)
    grid, u0, v0 = _splat(smp @ u, smp @ v, smp @ l, cell)
    ph = P @ l
    occ_h = _lookup(grid, u0, v0, cell, P @ u, P @ v)
    ndl = np.clip(np.asarray(normals, np.float64) @ l, 0.2, 1.0)
    # slope-scaled: a surface at a grazing angle to the light rises across a cell
    bias = bias_rel * np.maximum(-P[:, 2], 1e-6) + 1.5 * cell + 2 * cell * np.sqrt(1 - ndl ** 2) / ndl
    blocked = occ_h > ph + bias
    vis = (~blocked).astype(np.float64)
    t_hit = np.where(blocked, occ_h - ph, np.inf)
    return vis, t_hit


def mesh_shadow_point(mesh: PosedMesh, points: np.ndarray, normals: np.ndarray, position, *,
                      bias_rel: float | None = None, cfg: ObjectShadowConfig | None = None):
    """Visibility of camera-frame ``points`` (N, 3) toward a lamp at ``position`` (3,)
    past the mesh: a perspective shadow map from the lamp (the mesh's samples splatted
    by their direction from it, keeping the nearest to it per cell; ``cfg`` as for
    ``mesh_shadow``). A lamp that sees the mesh within ``cfg.lamp_one_map_tan`` of its centre
    gets one map toward it, covering only the field of the receivers in front of it, at
    most ``cfg.lamp_map_cells`` cells; a lamp beside or inside the object (a lampshade)
    a cube map (``_cube_heights``): either way the memory is bounded.

    Returns:
        (vis (N,) in {0, 1}, t_hit (N,) distance to the occluder, inf where lit).
    """
    cfg, bias_rel = _defaults(cfg, bias_rel)
    q = np.asarray(position, np.float64)
    P = np.asarray(points, np.float64)
    _, _, area, _ = area_triangles(mesh)
    if not area.sum() > 0 or not len(P):
        return np.ones(len(P)), np.full(len(P), np.inf)
    V = mesh.vertices[np.all(np.isfinite(mesh.vertices), axis=1)]
    axis = V.mean(0) - q
    dist_c = float(np.linalg.norm(axis))
    d = P - q
    one = None
    if dist_c > 1e-9:
        one = _one_map_heights(mesh, q, V - q, d, axis / dist_c, dist_c, cfg)
    occ, cell = one if one is not None else _cube_heights(mesh, q, V - q, d, cfg)
    r = np.linalg.norm(d, axis=1)
    l = -d / np.maximum(r, 1e-12)[:, None]
    ndl = np.clip(np.sum(np.asarray(normals, np.float64) * l, axis=1), 0.2, 1.0)
    cell_m = cell * r  # a cell's size at the point's distance
    bias = bias_rel * np.maximum(-P[:, 2], 1e-6) + 1.5 * cell_m + 2 * cell_m * np.sqrt(1 - ndl ** 2) / ndl
    blocked = -occ < r - bias
    vis = (~blocked).astype(np.float64)
    t_hit = np.where(blocked, r + occ, np.inf)
    return vis, t_hit


def _one_map_heights(mesh, q, Vq, d, axis, dist_c, cfg):
    """One gnomonic map along ``axis`` from the lamp at ``q`` (``Vq``: the vertices,
    ``d``: the receivers, both less ``q``): (heights (N,): minus the distance to the nearest sample toward the
    lamp, -inf where none; the map's cell in tangent units), or None when the lamp sees
    the mesh wider than ``cfg.lamp_one_map_tan`` about ``axis`` (or part of it behind)."""
    u, v = orthonormal(axis)
    fwd = Vq @ axis
    if not (fwd > 1e-6).all():
        return None
    tu, tv = (Vq @ u) / fwd, (Vq @ v) / fwd
    if max(np.abs(tu).max(), np.abs(tv).max()) > cfg.lamp_one_map_tan:
        return None
    # the vertices' extent in tangents sets the cell (the map's resolution across the mesh)
    ext = max(float(np.ptp(tu)), float(np.ptp(tv))) + 1e-9
    cell = ext / cfg.mesh_shadow_cells
    occ = np.full(len(d), -np.inf)
    df = d @ axis
    front = df > cfg.lamp_near_plane_tan * np.linalg.norm(d, axis=1)
    smp = _samples(mesh, ext * dist_c, cell * dist_c, cfg) - q
    sf = smp @ axis
    keep = sf > cfg.lamp_near_plane_tan * np.linalg.norm(smp, axis=1)  # at or behind the lamp's plane: dropped
    if not front.any() or not keep.any():
        return occ, cell
    smp, sf = smp[keep], sf[keep]
    ru, rv = (d[front] @ u) / df[front], (d[front] @ v) / df[front]
    occ[front], cell = _field_map(smp, (smp @ u) / sf, (smp @ v) / sf, ru, rv, cell, cfg.lamp_map_cells)
    return occ, cell


def _field_map(smp, su, sv, ru, rv, cell, max_cells):
    """Heights (minus the distance from the lamp, the nearest sample winning) the
    receivers at tangents (``ru``, ``rv``) look up in a map of samples ``smp`` at
    tangents (``su``, ``sv``): the map covers the samples' box cut to the receivers' (a
    sample no receiver looks at is left out), its ``cell`` grown where that field would
    pass ``max_cells``. Returns (heights, the cell used)."""
    out = np.full(len(ru), -np.inf)
    u0, u1 = max(su.min(), ru.min()), min(su.max(), ru.max())
    v0, v1 = max(sv.min(), rv.min()), min(sv.max(), rv.max())
    if u0 > u1 or v0 > v1:  # no receiver looks past the mesh
        return out, cell
    cell = max(cell, float(np.sqrt((u1 - u0 + 8 * cell) * (v1 - v0 + 8 * cell) / max_cells)))
    m = 2 * cell  # a sample just outside the field still closes a receiver's cell
    ins = (su >= u0 - m) & (su <= u1 + m) & (sv >= v0 - m) & (sv <= v1 + m)
    grid, g0u, g0v = _splat(su[ins], sv[ins], -np.linalg.norm(smp[ins], axis=1), cell)
    return _lookup(grid, g0u, g0v, cell, ru, rv), cell


def _cube_heights(mesh, q, Vq, d, cfg):
    """The heights (as ``_one_map_heights``) of a cube map about the lamp at ``q``: six
    gnomonic faces, each over tangents within 1 (each receiver and sample on the face of
    its dominant axis, samples also a few cells past it so that the edges close), each
    at most ``cfg.mesh_shadow_cells`` cells wide and no finer than its samples cover
    (``cfg.mesh_sample_density`` a cell). Returns (heights, the coarsest cell)."""
    fine = 2.0 / cfg.mesh_shadow_cells
    near = max(float(np.linalg.norm(Vq, axis=1).min()), 1e-6)
    smp = _samples(mesh, 2.0 * near, fine * near, cfg) - q
    occ = np.full(len(d), -np.inf)
    used = fine
    for k in range(3):
        o1, o2 = (k + 1) % 3, (k + 2) % 3
        for sgn in (1.0, -1.0):
            a_r, a_s = sgn * d[:, k], sgn * smp[:, k]
            rec = (a_r > 0) & (np.abs(d[:, o1]) <= a_r) & (np.abs(d[:, o2]) <= a_r)
            lim = (1.0 + 8 * fine) * a_s
            sm = (a_s > 0) & (np.abs(smp[:, o1]) <= lim) & (np.abs(smp[:, o2]) <= lim)
            if not rec.any() or not sm.any():
                continue
            su, sv = smp[sm, o1] / a_s[sm], smp[sm, o2] / a_s[sm]
            cell = max(fine, float(np.sqrt(np.ptp(su) * np.ptp(sv) * cfg.mesh_sample_density / sm.sum())))
            occ[rec], cell = _field_map(smp[sm], su, sv, d[rec, o1] / a_r[rec], d[rec, o2] / a_r[rec], cell,
                                        cfg.lamp_map_cells)
            used = max(used, cell)
    return occ, used


def _defaults(cfg, bias_rel):
    """The shadow map's config and bias, each None: the defaults (a caller with a light
    config passes its own)."""
    from zcomp_cli.scene.config import MarchConfig

    return (ObjectShadowConfig() if cfg is None else cfg,
            MarchConfig().march_bias_rel if bias_rel is None else bias_rel)


def light_shadow(mesh: PosedMesh, points: np.ndarray, normals: np.ndarray, light, *, bias_rel: float,
                 cfg: ObjectShadowConfig):
    """The mesh's shadow from a model light (``lightmodel.Sun`` or ``Lamp``) at camera-
    frame ``points`` (N, 3): (vis (N,) in {0, 1}, t_hit (N,))."""
    if getattr(light, "varies", False):
        return mesh_shadow_point(mesh, points, normals, light.position, bias_rel=bias_rel, cfg=cfg)
    return mesh_shadow(mesh, points, normals, light.direction, bias_rel=bias_rel, cfg=cfg)


__all__ = ["light_shadow", "area_triangles", "sample_triangles", "mesh_silhouette", "mesh_shadow", "mesh_shadow_point"]
