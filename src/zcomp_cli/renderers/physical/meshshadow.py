"""The sky the inserted object hides, from its real posed mesh (its shadow from each
light is ``scene.objectshadow``'s).

The sky the object hides (``mesh_occlusion``) is summed over area elements of the mesh
(form factors), and, close to the mesh, over its triangles (exact form factors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from zcomp_cli.posed_mesh import PosedMesh  # (geometry: it lives below the renderers)
from zcomp_cli.renderers.physical.settings import TransportConfig
from zcomp_cli.scene.objectshadow import sample_triangles, area_triangles


@dataclass
class MeshDiscs:
    """Area elements of a posed mesh: centres (M, 3), outward unit normals (M, 3) and
    areas (M,), camera frame, metres."""

    centres: np.ndarray
    normals: np.ndarray
    areas: np.ndarray


def mesh_discs(mesh: PosedMesh, n: int | None = None, cfg: TransportConfig | None = None) -> MeshDiscs:
    """``n`` (None: ``cfg.mesh_ao_discs``: enough that a floor point near the object's
    base sees many, few enough that points x discs stays cheap, 34 ms a job at 512x512)
    area-weighted surface samples of the posed mesh, each standing for an equal share of
    its area, with its face's normal (deterministic).

    Normals point out of the mesh: the faces' winding gives them, and a mesh whose
    signed volume is negative (wound inside out) has them all turned."""
    cfg = TransportConfig() if cfg is None else cfg
    n = cfg.mesh_ao_discs if n is None else n
    tri, cr, area, inside_out = area_triangles(mesh)
    if not len(tri):
        z = np.zeros((0, 3))
        return MeshDiscs(z, z, np.zeros(0))
    nrm = cr / (2.0 * area[:, None])
    if inside_out:
        nrm = -nrm
    pick, c = sample_triangles(tri, area / area.sum(), n)
    return MeshDiscs(c, nrm[pick], np.full(n, area.sum() / n))


def mesh_occlusion(discs: MeshDiscs, points: np.ndarray, normals: np.ndarray, *,
                   mesh: PosedMesh | None = None, refine: np.ndarray | None = None,
                   chunk: int = 2048, return_distance: bool = False, radiance_sh: np.ndarray | None = None,
                   cfg: TransportConfig | None = None):
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
    cfg = TransportConfig() if cfg is None else cfg
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
            whole = area_triangles(mesh)
            near_mesh = _near_field_mesh(mesh, np.sqrt(rho2), area=whole[2], cfg=cfg)
            tri, _, _, inside_out = whole if near_mesh is mesh else area_triangles(near_mesh)
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
            from zcomp_cli.scene import sh

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
                     cfg: TransportConfig | None = None) -> PosedMesh:
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
    cfg = TransportConfig() if cfg is None else cfg
    n_tri = cfg.near_field_triangles
    if area is None:
        area = area_triangles(mesh)[2]
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
