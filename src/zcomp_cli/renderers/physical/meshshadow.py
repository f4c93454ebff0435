"""The object's cast shadow and self-shadowing from its real posed mesh.

The 2.5D composite depth has no back side: a thin object's shadow is cut where rays
pass "behind" its visible shell. With the object bundle's mesh and pose (``meta.json``:
``mesh``, ``object_to_camera``), a shadow map is made from the light: surface samples of
the posed mesh (area-weighted) are splatted into an orthographic grid perpendicular to
the light, keeping per cell the height toward the light; a small max filter closes the
gaps between samples. A point is in the object's shadow when a cell it projects to holds
a surface higher (toward the light) than the point by more than a bias; the difference
is the occluder distance the penumbra filter needs.

The sky the object hides (``mesh_occlusion``) is summed over area elements of the mesh
(form factors), and, close to the mesh, over its triangles (exact form factors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.posed_mesh import PosedMesh  # (geometry: it lives below the renderers)
from zcomp_cli.renderers.physical.sampling import orthonormal
from zcomp_cli.renderers.physical.settings import TransportConfig

# The constants (the shadow map's cells and samples, the bias, the sky's area elements
# and the exact near field's reach) are ``settings.TransportConfig``'s, each with its
# provenance.
DEFAULT = TransportConfig()
# (the default near field's reach, in disc spacings, for callers that name it)
NEAR_SPACINGS = DEFAULT.near_field_spacings


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


def _sample_triangles(tri: np.ndarray, p: np.ndarray, n: int):
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


def _samples(mesh: PosedMesh, ext: float, cell: float, cfg: TransportConfig = DEFAULT):
    tri, _, area, _ = _area_triangles(mesh)
    n_s = int(min(cfg.mesh_max_samples, max(2000, cfg.mesh_sample_density * area.sum() / cell ** 2)))
    return _sample_triangles(tri, area / max(area.sum(), 1e-12), n_s)[1]


def mesh_shadow(mesh: PosedMesh, points: np.ndarray, normals: np.ndarray, light_dir, *,
                cell: float | None = None, bias_rel: float | None = None, cfg: TransportConfig = DEFAULT):
    """Visibility of camera-frame ``points`` (N, 3) toward ``light_dir`` past the mesh
    (``cell`` None: the extent over ``cfg.mesh_shadow_cells``; ``bias_rel`` None:
    ``cfg.march_bias_rel``).

    Returns:
        (vis (N,) in {0, 1}, t_hit (N,) distance to the occluder, inf where lit).
    """
    l = np.asarray(light_dir, np.float64)
    l = l / np.linalg.norm(l)
    u, v = orthonormal(l)
    # a non-finite corner drops its triangle (as the silhouette and the sky's elements
    # do); a mesh left without area shadows nothing (sampling it raised a ValueError)
    _, _, area, _ = _area_triangles(mesh)
    P = np.asarray(points, np.float64)
    if not area.sum() > 0:
        return np.ones(len(P)), np.full(len(P), np.inf)
    V = mesh.vertices[np.all(np.isfinite(mesh.vertices), axis=1)]
    ext = np.ptp(V @ np.stack([u, v], 1), axis=0).max() + 1e-9
    if cell is None:
        cell = ext / cfg.mesh_shadow_cells
    if bias_rel is None:
        bias_rel = cfg.march_bias_rel
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


# The lamp's shadow map at most this many cells, whatever the lamp's place (a lamp 1 cm
# beside a box made a grid of 11 GB from the tangents of samples near its plane): 4 Mi
# float64 cells, 32 MB (and as much for the max filter), about what a 2048 x 2048 map
# of the image costs; the grid covers only the receivers' field, so it is met by
# coarser cells only where the receivers' field is that much wider than the mesh.
MAX_LAMP_MAP_CELLS = 1 << 22
# Samples and receivers within this angle of the lamp's plane are left out of its
# gnomonic map (their tangents pass 1 / NEAR_PLANE_TAN): at 1e-3, 0.06 deg.
NEAR_PLANE_TAN = 1e-3
# One gnomonic map serves a lamp that sees the mesh within this tangent of its centre
# (45 deg); a lamp nearer (beside the object, inside a lampshade) sees it over a wider
# field, where one map's cells stretch (a cell at tangent 3 is 10 times narrower than
# at the centre): it gets a cube map, six faces of tangents within 1.
ONE_MAP_MAX_TAN = 1.0


def mesh_shadow_point(mesh: PosedMesh, points: np.ndarray, normals: np.ndarray, position, *,
                      bias_rel: float | None = None, cfg: TransportConfig = DEFAULT):
    """Visibility of camera-frame ``points`` (N, 3) toward a lamp at ``position`` (3,)
    past the mesh: a perspective shadow map from the lamp (the mesh's samples splatted
    by their direction from it, keeping the nearest to it per cell; ``cfg`` as for
    ``mesh_shadow``). A lamp that sees the mesh within ``ONE_MAP_MAX_TAN`` of its centre
    gets one map toward it, covering only the field of the receivers in front of it, at
    most ``MAX_LAMP_MAP_CELLS`` cells; a lamp beside or inside the object (a lampshade)
    a cube map (``_cube_heights``): either way the memory is bounded.

    Returns:
        (vis (N,) in {0, 1}, t_hit (N,) distance to the occluder, inf where lit).
    """
    q = np.asarray(position, np.float64)
    P = np.asarray(points, np.float64)
    lit = np.ones(len(P)), np.full(len(P), np.inf)
    _, _, area, _ = _area_triangles(mesh)
    if not area.sum() > 0 or not len(P):
        return lit
    if bias_rel is None:
        bias_rel = cfg.march_bias_rel
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
    the mesh wider than ``ONE_MAP_MAX_TAN`` about ``axis`` (or part of it behind)."""
    u, v = orthonormal(axis)
    fwd = Vq @ axis
    if not (fwd > 1e-6).all():
        return None
    tu, tv = (Vq @ u) / fwd, (Vq @ v) / fwd
    if max(np.abs(tu).max(), np.abs(tv).max()) > ONE_MAP_MAX_TAN:
        return None
    # the vertices' extent in tangents sets the cell (the map's resolution across the mesh)
    ext = max(float(np.ptp(tu)), float(np.ptp(tv))) + 1e-9
    cell = ext / cfg.mesh_shadow_cells
    occ = np.full(len(d), -np.inf)
    df = d @ axis
    front = df > NEAR_PLANE_TAN * np.linalg.norm(d, axis=1)
    smp = _samples(mesh, ext * dist_c, cell * dist_c, cfg) - q
    sf = smp @ axis
    keep = sf > NEAR_PLANE_TAN * np.linalg.norm(smp, axis=1)  # at or behind the lamp's plane: dropped
    if not front.any() or not keep.any():
        return occ, cell
    smp, sf = smp[keep], sf[keep]
    ru, rv = (d[front] @ u) / df[front], (d[front] @ v) / df[front]
    occ[front], cell = _field_map(smp, (smp @ u) / sf, (smp @ v) / sf, ru, rv, cell)
    return occ, cell


def _field_map(smp, su, sv, ru, rv, cell):
    """Heights (minus the distance from the lamp, the nearest sample winning) the
    receivers at tangents (``ru``, ``rv``) look up in a map of samples ``smp`` at
    tangents (``su``, ``sv``): the map covers the samples' box cut to the receivers' (a
    sample no receiver looks at is left out), its ``cell`` grown where that field would
    pass ``MAX_LAMP_MAP_CELLS``. Returns (heights, the cell used)."""
    out = np.full(len(ru), -np.inf)
    u0, u1 = max(su.min(), ru.min()), min(su.max(), ru.max())
    v0, v1 = max(sv.min(), rv.min()), min(sv.max(), rv.max())
    if u0 > u1 or v0 > v1:  # no receiver looks past the mesh
        return out, cell
    cell = max(cell, float(np.sqrt((u1 - u0 + 8 * cell) * (v1 - v0 + 8 * cell) / MAX_LAMP_MAP_CELLS)))
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
            occ[rec], cell = _field_map(smp[sm], su, sv, d[rec, o1] / a_r[rec], d[rec, o2] / a_r[rec], cell)
            used = max(used, cell)
    return occ, used


@dataclass
class MeshDiscs:
    """Area elements of a posed mesh: centres (M, 3), outward unit normals (M, 3) and
    areas (M,), camera frame, metres."""

    centres: np.ndarray
    normals: np.ndarray
    areas: np.ndarray


def _area_triangles(mesh: PosedMesh):
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


def mesh_discs(mesh: PosedMesh, n: int | None = None, cfg: TransportConfig = DEFAULT) -> MeshDiscs:
    """``n`` (None: ``cfg.mesh_ao_discs``: enough that a floor point near the object's
    base sees many, few enough that points x discs stays cheap, 34 ms a job at 512x512)
    area-weighted surface samples of the posed mesh, each standing for an equal share of
    its area, with its face's normal (deterministic).

    Normals point out of the mesh: the faces' winding gives them, and a mesh whose
    signed volume is negative (wound inside out) has them all turned."""
    n = cfg.mesh_ao_discs if n is None else n
    tri, cr, area, inside_out = _area_triangles(mesh)
    if not len(tri):
        z = np.zeros((0, 3))
        return MeshDiscs(z, z, np.zeros(0))
    nrm = cr / (2.0 * area[:, None])
    if inside_out:
        nrm = -nrm
    pick, c = _sample_triangles(tri, area / area.sum(), n)
    return MeshDiscs(c, nrm[pick], np.full(n, area.sum() / n))


def mesh_occlusion(discs: MeshDiscs, points: np.ndarray, normals: np.ndarray, *,
                   mesh: PosedMesh | None = None, refine: np.ndarray | None = None,
                   chunk: int = 2048, return_distance: bool = False, radiance_sh: np.ndarray | None = None,
                   cfg: TransportConfig = DEFAULT):
    """Share of the cosine-weighted hemisphere of each point (N, 3) with unit normal
    (N, 3) that the mesh hides: (N,) in [0, 1]; with ``return_distance`` also (N,) the
    distance (metres) to the nearest area element. With ``radiance_sh`` (9, C), the
    share of the irradiance of a sky of that SH radiance instead, (N, C): each element
    hides its form factor times the sky's radiance behind it (a low bright sky's
    shadow is cast away from it).

    Each disc (area ``A`` at distance ``r`` along ``w``) hides its form factor
    ``A max(0, n . w) max(0, -n_j . w) / (pi r^2 + A)`` (the ``+ A`` keeps a disc
    finite when a point touches it). Only discs turned toward the point count: on a
    closed mesh they cover its silhouette once, where the back faces would count it
    twice. Smooth by construction (no discrete directions, no star of copies), and the
    range is unlimited, as the sky's occlusion is: the screen-space occlusion reaches
    10 % of the depth and, marching the object's 2.5D shell as a solid slab, hid most
    of the sky from the floor seen under a chair's seat (0.27 where rays cast at the
    mesh give 0.6-0.7).

    ``mesh``: the mesh the discs were cut from. Within ``cfg.near_field_spacings`` disc
    spacings of a point the discs are too few to stand for what is that close (a floor point by a
    sphere's contact saw one or two, and read lighter than a ring around it): there the
    mesh's own triangles count instead, each with its exact form factor (Lambert's
    polygon formula, ``_triangle_form_factors``). ``refine``: (N,) bool, the points this
    applies to (default all); the object's own points, each near hundreds of its
    triangles, are better left out (a 20480-face sphere's cost x7, for the self-occlusion
    of concave parts only).
    """
    P = np.asarray(points, np.float64)
    Nn = np.asarray(normals, np.float64)
    C = 1 if radiance_sh is None else np.asarray(radiance_sh).reshape(9, -1).shape[1]
    out = np.zeros((len(P), C))
    dmin = np.full(len(P), np.inf)
    if len(P) == 0 or len(discs.areas) == 0:
        out = out[:, 0] if radiance_sh is None else out
        return (out, dmin) if return_distance else out
    weigh = _radiance_weights(radiance_sh, Nn, discs.centres)
    rho2 = cfg.near_field_spacings ** 2 * float(discs.areas.mean()) if mesh is not None else 0.0
    for i in range(0, len(P), chunk):
        f, r2 = _form_factors(discs, P[i:i + chunk], Nn[i:i + chunk])
        out[i:i + chunk] = weigh.summed(f, r2, P[i:i + chunk], np.arange(i, min(i + chunk, len(P))))
        dmin[i:i + chunk] = np.sqrt(r2.min(1))
    if mesh is not None:
        idx = np.flatnonzero((dmin ** 2 < rho2) & (True if refine is None else np.asarray(refine, bool)))
        if len(idx):
            # the discs' share within the radius, which the triangles replace (few
            # points: computed again for them rather than kept for all)
            f, r2 = _form_factors(discs, P[idx], Nn[idx])
            part = np.zeros((len(P), C))
            part[idx] = weigh.per_element(f * (r2 < rho2), P[idx], idx)
            whole = _area_triangles(mesh)
            near_mesh = _near_field_mesh(mesh, np.sqrt(rho2), area=whole[2], cfg=cfg)
            tri, _, _, inside_out = whole if near_mesh is mesh else _area_triangles(near_mesh)
            if inside_out:  # wound outward, as the discs' normals are
                tri = tri[:, ::-1]
            cen = tri.mean(1)
            rad = np.sqrt(((tri - cen[:, None]) ** 2).sum(-1).max(1))
            # only triangles near the box of these points can be within the radius
            reach = np.sqrt(rho2) + rad.max()
            near = np.all((cen >= P[idx].min(0) - reach) & (cen <= P[idx].max(0) + reach), axis=1)
            tri, cen, rad = tri[near], cen[near], rad[near]
            c2 = (cen * cen).sum(1)[None]
            for i in range(0, len(idx), 256):
                j = idx[i:i + 256]
                # (n, T) distances to the triangles' centres, as a GEMM
                dc = np.sqrt(np.maximum(c2 + (P[j] * P[j]).sum(1)[:, None] - 2.0 * (P[j] @ cen.T), 0.0))
                pi, ti = np.nonzero(dc < np.sqrt(rho2) + rad[None])
                ff = _triangle_form_factors(tri[ti], P[j][pi], Nn[j][pi])
                # a triangle counts where its centre is within the radius, as a disc did
                ff *= dc[pi, ti] < np.sqrt(rho2)
                fw = weigh.pairs(ff, cen[ti] - P[j][pi], j[pi])
                out[j] += np.stack([np.bincount(pi, fw[:, c], minlength=len(j)) for c in range(C)], 1) - part[j]
    out = np.clip(out, 0.0, 1.0)
    out = out[:, 0] if radiance_sh is None else out
    return (out, dmin) if return_distance else out


class _radiance_weights:
    """Form factors (n, M) of elements seen from their points, summed per point: plainly
    (a uniform sky), or weighted by a sky of SH radiance behind each element over the
    point's whole sky shading (a share of that sky's irradiance).

    ``summed`` does the weighted sum without building the (n, M) radiances where it can
    do so exactly: the radiance is the quadratic ``a + b.u + u^T A u`` of the unit
    direction ``u`` (``sh.quadratic_form``), so its form-factor-weighted sum is ``a F0 +
    b.F1 + A:F2`` with the moments ``F0 = sum f``, ``F1 = sum f u``, ``F2 = sum f u u^T``
    -- GEMMs of ``f / r`` and ``f / r^2`` with the elements' centres and their products.
    That equals the clamped sum (radiance below 0, order 2's ringing, counts 0) for a
    point whose counted elements all lie where the radiance is positive. An element
    counts (``f > 0``) only in the point's upper hemisphere (``w . n > 0``) and within
    the cone of the elements' bounding sphere (half-angle ``t`` about the axis ``u0``;
    the whole sphere of directions from a point inside it). Where the radiance may be
    negative is found once per sky (``_negative_cells``): cells of a cube map whose
    bound ``L(c) - |b + 2 A c| t_c - |A| t_c^2`` (``t_c`` the cell's angular radius) is
    below 0 -- along a great circle the radiance's rate of change is at most ``|b + 2 A
    u|``, within ``2 |A| s`` of its value at ``c`` after an arc ``s``. A point none of
    whose cells meets its hemisphere and its cone takes the moments: for a sky that
    never rings below 0, every point.
    The others (a point facing the ringing, below the horizon, with elements in view)
    evaluate and clamp the radiance of each element they count, and only those
    (``per_element``: the pairs with ``f > 0``). The moments replaced most of a posed
    mesh's sky-occlusion cost (issue 39's speed regression)."""

    def __init__(self, radiance_sh, normals, centres=None):
        self.c = None if radiance_sh is None else np.asarray(radiance_sh, np.float64).reshape(9, -1)
        self.centres = None if centres is None else np.asarray(centres, np.float64)
        self.normals = np.asarray(normals, np.float64)
        if self.c is not None:
            from zcomp_cli.renderers.physical import sh

            self.total = np.maximum(sh.evaluate(sh.shading_coeffs(self.c), normals), 1e-9)
            # the radiance as a polynomial of the direction (``sh.quadratic_form``), in
            # float32 as the form factors are: the (n M, 9) basis of every element seen
            # from every point was most of the cost of a posed mesh's sky occlusion
            a, b, A = sh.quadratic_form(self.c)
            nc = self.c.shape[1]
            self._a, self._b = a.astype(np.float32), b.astype(np.float32)
            self._A = A.reshape(3, 3 * nc).astype(np.float32)
            self._a64, self._b64, self._A64 = a, b, A
            # the spectral norm of each colour's (symmetric) quadratic part
            normA = np.array([np.abs(np.linalg.eigvalsh(0.5 * (A[..., k] + A[..., k].T))).max()
                              for k in range(nc)])
            self._neg, self._neg_t = _negative_cells(a, b, A, normA)
            self._neg32 = self._neg.astype(np.float32)
            if self.centres is not None and len(self.centres):
                o = self.centres.mean(0)
                self._origin = o
                cc = self.centres - o
                # (M, .) centred, small numbers for float32 GEMMs: the centres, their
                # products, a column of ones for the sums
                one = np.ones((len(cc), 1))
                self._ones = np.ones(len(cc), np.float32)
                self._cc1 = np.hstack([cc, one]).astype(np.float32)
                self._cc2 = np.hstack([cc, (cc[:, :, None] * cc[:, None, :]).reshape(-1, 9), one]).astype(np.float32)
                self._R = float(np.sqrt(((cc) ** 2).sum(1).max()))

    def _safe(self, po, rows):
        """(n,) bool: the points at ``po`` (n, 3) from the elements' centre, normals
        ``self.normals[rows]``, that count no element where the radiance may be negative."""
        if not len(self._neg):
            return np.ones(len(po), bool)
        n = self.normals[rows].astype(np.float32)
        # (every cell taken as wide as the widest: two GEMMs and no (n, k) trigonometry)
        t = float(self._neg_t.max())
        # a cell meets the open hemisphere of n where its centre is within 90 deg + t of n
        meets = (n @ self._neg32.T) > (-np.sin(t) * np.linalg.norm(n, axis=1))[:, None]
        dist = np.linalg.norm(po, axis=1)
        far = dist > self._R * (1.0 + 1e-6)
        if far.any():
            # ... and the cone of the bounding sphere where the point is outside it
            axis = (-po[far] / dist[far, None]).astype(np.float32)
            ang = np.arcsin(np.clip(self._R / dist[far], 0.0, 1.0))
            meets[far] &= (axis @ self._neg32.T) > np.cos(np.minimum(ang + t, np.pi))[:, None]
        return ~meets.any(1)

    def summed(self, f, r2, points, rows):
        """``per_element`` for every element of ``centres`` (f, r2: (n, M) form factors and
        squared distances from ``points`` (n, 3)); moments where exact, else per element."""
        if self.c is None:
            return f.sum(1)[:, None]
        if self.centres is None or not len(self.centres):
            raise ValueError("_radiance_weights.summed needs the elements' centres")
        P = np.asarray(points, np.float64)
        rows = np.asarray(rows)
        po = P - self._origin
        safe = self._safe(po, rows)
        out = np.zeros((len(P), self.c.shape[1]))
        if safe.any():
            s_ = slice(None) if safe.all() else np.flatnonzero(safe)  # (no copy when all are)
            fs = np.asarray(f[s_], np.float32)
            r = np.sqrt(np.maximum(np.asarray(r2[s_], np.float32), np.float32(1e-24)))
            g1 = fs / r
            g2 = np.divide(g1, r, out=r)
            p = po[s_]
            # the sums ride in the GEMMs as a column of ones (float32 accumulation, as
            # the moments themselves: a relative 1e-6)
            F0 = (fs @ self._ones).astype(np.float64)
            m1 = (g1 @ self._cc1).astype(np.float64)  # (centres, 1)
            m2 = (g2 @ self._cc2).astype(np.float64)  # (centres, their products, 1)
            s1, s2, t2 = m1[:, 3], m2[:, 12], m2[:, :3]
            F1 = m1[:, :3] - p * s1[:, None]
            F2 = m2[:, 3:12].reshape(-1, 3, 3) - t2[:, :, None] * p[:, None, :] \
                - p[:, :, None] * t2[:, None, :] + s2[:, None, None] * p[:, :, None] * p[:, None, :]
            val = F0[:, None] * self._a64[None] + F1 @ self._b64 + np.einsum("kij,ijc->kc", F2, self._A64)
            out[s_] = val / self.total[rows[s_]]
        if (~safe).any():
            u_ = np.flatnonzero(~safe)
            out[u_] = self.per_element(f[u_], P[u_], rows[u_])
        return out

    def _L(self, offsets):
        """(K, C) the radiance toward ``offsets`` (..., 3), not normalised: the
        polynomial's linear and quadratic terms are divided by the length and its
        square instead."""
        w = np.asarray(offsets, np.float32).reshape(-1, 3)
        r2 = np.einsum("kj,kj->k", w, w)
        inv2 = 1.0 / np.maximum(r2, np.float32(1e-24))
        nc = len(self._a)
        quad = np.einsum("kjc,kj->kc", (w @ self._A).reshape(-1, 3, nc), w)
        quad *= inv2[:, None]
        lin = w @ self._b
        lin *= np.sqrt(inv2)[:, None]
        quad += lin
        quad += self._a
        return np.maximum(quad, 0.0, out=quad)

    def per_element(self, f, points, rows):
        """(n, C): the form factors ``f`` (n, M) >= 0 of every element of ``centres``
        seen from ``points`` (n, 3), each times the clamped radiance behind it, summed,
        over each point's sky shading (``rows``: the points' indices into the normals).
        Only the pairs with ``f > 0`` are evaluated: an element a point does not count
        costs nothing."""
        f = np.asarray(f, np.float32)
        if self.c is None:
            return f.sum(1, dtype=np.float64)[:, None]
        pi, mi = np.nonzero(f > 0)
        off = self.centres[mi].astype(np.float32) - np.asarray(points, np.float64)[pi].astype(np.float32)
        fw = self.pairs(f[pi, mi], off, np.asarray(rows)[pi])
        return np.stack([np.bincount(pi, fw[:, c], minlength=len(f)) for c in range(fw.shape[1])], 1)

    def pairs(self, ff, offsets, rows):
        """(K, C): the form factors ``ff`` (K,) of (point, element) pairs, each times the
        clamped radiance toward its offset (K, 3), over its point's (``rows`` (K,)) sky
        shading."""
        if self.c is None:
            return np.asarray(ff, np.float64)[:, None]
        return np.asarray(ff, np.float64)[:, None] * self._L(offsets) / self.total[rows]


def _negative_cells(a, b, A, norm_A, m: int = 16):
    """Where the radiance ``a + b.u + u^T A u`` (``sh.quadratic_form``, C colours) may
    fall below 0 on the unit sphere: the cells of an ``m`` x ``m`` per face cube map
    (``m`` only sets how tight the answer is: 16 gives cells of at most ~4 deg)
    whose lower bound ``L(c) - |b + 2 A c| t - |A| t^2`` is below 0 for some colour
    (``c`` the cell's centre direction, ``t`` the angle to its farthest corner, ``|A|``
    ``norm_A`` (C,)): (centres (k, 3) unit, angular radii (k,))."""
    g = (np.arange(m + 1) / m) * 2.0 - 1.0  # the cells' edges on a face
    mid = 0.5 * (g[:-1] + g[1:])
    cen, rad = [], []
    for ax in range(3):
        e0, e1, e2 = np.eye(3)[ax], np.eye(3)[(ax + 1) % 3], np.eye(3)[(ax + 2) % 3]
        for sgn in (1.0, -1.0):
            s, t = np.meshgrid(mid, mid, indexing="ij")
            c = sgn * e0 + s[..., None] * e1 + t[..., None] * e2
            c /= np.linalg.norm(c, axis=-1, keepdims=True)
            worst = np.full(s.shape, 1.0)
            for ds in (0, 1):
                for dt in (0, 1):
                    k = sgn * e0 + g[ds:m + ds, None, None] * e1 + g[None, dt:m + dt, None] * e2
                    k = k / np.linalg.norm(k, axis=-1, keepdims=True)
                    worst = np.minimum(worst, np.sum(c * k, -1))
            cen.append(c.reshape(-1, 3))
            rad.append(np.arccos(np.clip(worst, -1.0, 1.0)).reshape(-1))
    c, t = np.concatenate(cen), np.concatenate(rad)
    L0 = a[None] + c @ b + np.einsum("ki,kj,ijc->kc", c, c, A)
    g0 = np.linalg.norm(b[None] + 2.0 * np.einsum("ijc,kj->kic", A, c), axis=1)
    low = L0 - g0 * t[:, None] - norm_A[None] * (t * t)[:, None]
    neg = np.any(low < 0.0, axis=1)
    return c[neg], t[neg]


def _near_field_mesh(mesh: PosedMesh, radius: float, area: np.ndarray | None = None,
                     cfg: TransportConfig = DEFAULT) -> PosedMesh:
    """The mesh as the exact near field of radius ``radius`` uses it: itself, unless its
    mean triangle is smaller than that disc's area / ``cfg.near_field_triangles`` (a
    dense mesh, a scan, put 16 times the 20480-face sphere's triangles there, and the
    exact form factors cost 0.4 s a job); then its vertices merged on a grid whose cells
    hold one such triangle (vertex clustering: each cell's vertices become their mean,
    faces left with fewer than three distinct corners dropped). The surface moves by
    less than a cell, radius / 12.6. (With the radius ``mesh_occlusion`` uses, 2 spacings
    of 512 discs cut from the same area by default, this is a face count: more than
    512000 / (4 pi) = 40744 faces.) ``area``: the areas ``_area_triangles`` gives for
    the mesh, when the caller has them."""
    n_tri = cfg.near_field_triangles
    if area is None:
        area = _area_triangles(mesh)[2]
    if not len(area) or area.mean() >= np.pi * radius ** 2 / n_tri:
        return mesh
    cell = radius * np.sqrt(2.0 * np.pi / n_tri)  # a right triangle's legs
    V = np.asarray(mesh.vertices, np.float64)
    ok = np.all(np.isfinite(V), axis=1)
    # one integer per cell (a 1-D unique is ~10x an axis=0 one); a non-finite vertex
    # keeps a cluster of its own (its triangles are dropped later)
    ijk = np.floor(np.where(ok[:, None], V, 0.0) / cell).astype(np.int64)
    ijk -= ijk[ok].min(0) if ok.any() else 0
    span = ijk.max(0) + 1
    key = (ijk[:, 0] * span[1] + ijk[:, 1]) * span[2] + ijk[:, 2]
    key = np.where(ok, key, int(np.prod(span)) + np.arange(len(V)))
    _, inv = np.unique(key, return_inverse=True)
    inv = inv.reshape(-1)
    n = int(inv.max()) + 1
    cnt = np.bincount(inv, minlength=n).astype(np.float64)
    Vc = np.stack([np.bincount(inv, V[:, i], minlength=n) for i in range(3)], 1) / cnt[:, None]
    F = inv[np.asarray(mesh.faces)]
    keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])
    return PosedMesh(Vc, F[keep])


def _triangle_form_factors(tri: np.ndarray, P: np.ndarray, Nn: np.ndarray) -> np.ndarray:
    """(K,) exact form factor of each triangle tri (K, 3, 3) from the point P (K, 3)
    with unit normal Nn (K, 3) (Lambert: ``1/(2 pi) |sum_i theta_i n . unit(a_i x
    a_i+1)|`` over its edges, ``a_i`` the unit directions to its corners). 0 for a
    triangle turned away from the point or reaching below its horizon (those are
    dropped, not clipped: a concave corner's near field is slightly under-counted)."""
    a = tri - P[:, None]
    d = np.linalg.norm(a, axis=-1)
    ok = np.all(d > 1e-9, axis=1)
    a = a / np.maximum(d, 1e-12)[..., None]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    nt = np.cross(e1, e2)
    facing = np.einsum("kj,kj->k", nt, P - tri[:, 0]) > 0  # the point on its front side
    above = np.all(np.einsum("kij,kj->ki", a, Nn) > -1e-6, axis=1)
    tot = np.zeros(len(tri))
    for i in range(3):
        u, v = a[:, i], a[:, (i + 1) % 3]
        c = np.cross(u, v)
        cn = np.linalg.norm(c, axis=1)
        th = np.arccos(np.clip(np.einsum("kj,kj->k", u, v), -1.0, 1.0))
        tot += th * np.einsum("kj,kj->k", c, Nn) / np.maximum(cn, 1e-12)
    return np.where(ok & facing & above, np.abs(tot) / (2.0 * np.pi), 0.0)


def _form_factors(discs: MeshDiscs, P: np.ndarray, Nn: np.ndarray):
    """(n, M) form factors of the discs seen from points P (n, 3) with normals Nn, and
    the (n, M) squared distances; the distances in float32 GEMMs (w = c_j - p
    expanded)."""
    C = discs.centres.astype(np.float32)
    Nd = discs.normals.astype(np.float32)
    A = discs.areas.astype(np.float32)[None]
    p = P.astype(np.float32)
    q = Nn.astype(np.float32)
    r2 = np.maximum((C * C).sum(1)[None] + (p * p).sum(1)[:, None] - 2.0 * (p @ C.T), 0.0)
    wp = q @ C.T - (p * q).sum(1)[:, None]  # w . n_p
    wj = p @ Nd.T - (C * Nd).sum(1)[None]  # -w . n_j
    # A max(0, w.n_p) max(0, -w.n_j) / (r2 (pi r2 + A)), in place (these (n, M) arrays
    # are the cost)
    f = np.maximum(wp, 0.0, out=wp)
    f *= A
    f *= np.maximum(wj, 0.0, out=wj)
    den = np.multiply(r2, np.float32(np.pi))
    den += A
    den *= np.maximum(r2, 1e-18)
    f /= den
    return f, r2
