"""The photograph's geometry as a triangle mesh, for shadow rays (DESIGN.md section 8).

A depth map holds only the surfaces the camera sees. As a mesh:

* every 2 x 2 block of valid pixels makes two triangles, except across a **depth
  discontinuity**: an edge between two pixels is continuous when the plane of either
  pixel (its point and normal) predicts the other's depth (within ``step_share`` of the
  step it predicts, at most ``step_cap_rel`` of the depth, plus ``noise_rel``), or when
  the two are within ``join_rel`` of each other in depth or ``crease_px`` pixel
  footprints in space: a grazing floor steps far from pixel to
  pixel and stays whole, so do a box's top and front; a box's top edge and the floor
  seen past it do not, nor its side seen edge on and the floor beside it;
* the **support** is the plane the scene stands on: pixels facing up
  (``support_deg``) at the support's height (``support_height_rel`` of their distance);
  everything else valid is an **occluder**;
* each connected occluder is **extruded backwards**, away from the camera along the
  ground (its heights kept), so that it fills the ground distances from its nearest
  point to that plus its width (a thin shell lets a light ray pass behind the visible
  surface, where the real object stands: an object is taken to be about as deep as it
  is wide), and closed by side walls along its outline;
* an occluder's **base** is where it meets the support continuously (its pixels next to a
  support pixel across a continuous edge); a **caster** is an occluder with a base and a
  silhouette (somewhere its outline is a depth discontinuity in front of a farther
  surface): an object standing in the scene, whose shadow on the support is attached
  to it in the image. A wall meets the floor in a corner and the sky at its top: no
  silhouette, no caster (its shadow is cast by a top edge the frame rarely shows). With
  ``MeshConfig.sky_edges_cast``, an occluder edge with the sky (no geometry) above it is
  a silhouette too: a wall whose top edge is seen casts (off by default: measured,
  docs/design-notes.md, "A wall's long shadow");
* the walls beyond the frame (``planes.Wall``) join as large quads.

Pure numpy; ``RayCaster`` (``raycast``) answers the rays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import unit_normal_mask
from zcomp_cli.scene.config import MeshConfig
from zcomp_cli.scene.sampling import dot, length



def has_geometry(depth: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(h, w) bool: the pixels with geometry, a positive depth and a unit normal
    (``conventions.unit_normal_mask``). ``depth`` (h, w) and ``normals`` (h, w, 3)."""
    return (np.asarray(depth) > 0) & unit_normal_mask(normals)


@dataclass(frozen=True)
class DepthMesh:
    """The mesh and what its pixels are: ``vertices`` (V, 3), ``faces`` (F, 3) (camera
    frame, metres); per pixel of the (h, w) map: ``points`` (h, w, 3), ``valid``,
    ``support``, ``occluder`` (bool), ``labels`` (int, the occluder's component, 0
    none), ``base`` (occluder pixels standing on the support), ``casters`` (the pixels of
    occluders that stand on the support and show a silhouette: objects that cast the
    shadows a photograph is read from); ``support_height`` the
    support's height along ``up``."""

    vertices: np.ndarray
    faces: np.ndarray
    points: np.ndarray
    valid: np.ndarray
    support: np.ndarray
    occluder: np.ndarray
    labels: np.ndarray
    base: np.ndarray
    casters: np.ndarray
    up: np.ndarray
    support_height: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.valid.shape

    def caster(self):
        """A ``RayCaster`` of what can shadow the scene: the mesh less the support's own
        triangles (a plane does not shadow itself; most of a frame is floor)."""
        from zcomp_cli.scene.raycast import RayCaster

        h, w = self.shape
        sup = np.concatenate([self.support.ravel(), np.zeros(len(self.vertices) - h * w, bool)])
        keep = ~np.all(sup[self.faces], axis=1)
        return RayCaster(self.vertices, self.faces[keep])


def _continuous(Pa, Na, Pb, Nb, ra, rb, ok, cfg: MeshConfig | None = None):
    """(...) bool: pixels a and b (points P, unit normals N, rays r with z = -1; each
    (..., 3)) are continuous (module docstring), where ``ok``."""
    cfg = MeshConfig() if cfg is None else cfg
    za, zb = -Pa[..., 2], -Pb[..., 2]
    zmin = np.maximum(np.minimum(za, zb), 1e-9)
    small = np.abs(za - zb) <= cfg.join_rel * zmin
    # a pixel's footprint at that depth: the angle between the two rays times the depth
    crease = length(Pa - Pb) <= cfg.crease_px * zmin * length(ra - rb)

    def predicted(P, N, r, z_self, z_other):
        den = dot(N, r)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = dot(N, P) / den
        # (a step longer than ``step_max_rel`` of the depth is no surface's next pixel: a
        # face seen edge on, whose plane's extension merely passes the other point)
        good = np.isfinite(t) & (np.abs(den) > 1e-6) & (t > 0) & (np.abs(t - z_self) <= cfg.step_max_rel * z_self)
        # (a face seen edge on predicts an endless step: the share of it is capped)
        tol = (np.minimum(cfg.step_share * np.abs(t - z_self), cfg.step_cap_rel * z_other)
               + cfg.noise_rel * z_other)
        return good & (np.abs(t - z_other) <= tol)

    return ok & (small | crease | predicted(Pa, Na, rb, za, zb) | predicted(Pb, Nb, ra, zb, za))


# the (h, w) map's slices whose pixels pair as right, down and anti-diagonal neighbours
_EDGE_VIEWS = ((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]), (np.s_[:-1, 1:], np.s_[1:, :-1]))


def _edges(shape):
    """Index pairs (flat) of an (h, w) map's right, down and anti-diagonal neighbours
    (``_EDGE_VIEWS``, in its order)."""
    idx = np.arange(shape[0] * shape[1]).reshape(shape)
    return [(idx[a].ravel(), idx[b].ravel()) for a, b in _EDGE_VIEWS]


def support_mask(points: np.ndarray, normals: np.ndarray, valid: np.ndarray, up,
                 cfg: MeshConfig | None = None) -> tuple[np.ndarray, float]:
    """(support (h, w) bool, its height along ``up``): the pixels facing up
    (``cfg.support_deg``) at the most common height of those (within
    ``cfg.support_height_rel`` of their distance)."""
    cfg = MeshConfig() if cfg is None else cfg
    up = np.asarray(up, np.float64)
    facing = valid & (normals @ up > math.cos(math.radians(cfg.support_deg)))
    if facing.sum() < 3:
        return np.zeros(valid.shape, bool), float("nan")
    hgt = points @ up
    dist = np.linalg.norm(points, axis=-1)
    hv, dv = hgt[facing], dist[facing]
    # the lowest well-populated height: the floor, not a table top (both face up; the
    # floor is the support the scene stands on and most often the largest)
    tol = cfg.support_height_rel * dv
    order = np.argsort(hv)
    hs, ts = hv[order], tol[order]
    counts = np.searchsorted(hs, hs + ts, side="right") - np.searchsorted(hs, hs - ts, side="left")
    h0 = float(np.median(hs[np.abs(hs - hs[int(np.argmax(counts))]) <= ts[int(np.argmax(counts))]]))
    sup = facing & (np.abs(hgt - h0) <= cfg.support_height_rel * dist)
    return sup, h0


def build_depth_mesh(depth: np.ndarray, normals: np.ndarray, camera: Camera, up, *, valid=None,
                     walls=(), cfg: MeshConfig | None = None) -> DepthMesh:
    """The depth map's mesh (module docstring).

    Args:
        depth: (h, w) z-depth (metres, 0 invalid); normals: (h, w, 3) unit, camera frame.
        camera: the map's camera. up: (3,) world up, camera frame.
        valid: (h, w) bool, the pixels with geometry (default: depth > 0 and unit normals).
        walls: ``planes.Wall`` beyond the frame, added as quads.
        cfg: the mesh's constants (``settings.MeshConfig``).
    """
    cfg = MeshConfig() if cfg is None else cfg
    d = np.nan_to_num(np.asarray(depth, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    n = np.nan_to_num(np.asarray(normals, np.float64))
    h, w = d.shape
    nn = np.linalg.norm(n, axis=-1)
    ok = has_geometry(d, n) if valid is None else (np.asarray(valid, bool) & (d > 0))
    n = n / np.maximum(nn, 1e-12)[..., None]
    up = np.asarray(up, np.float64)
    up = up / max(float(np.linalg.norm(up)), 1e-12)
    P = camera.unproject(d.astype(np.float32)).astype(np.float64)
    ys, xs = np.mgrid[0:h, 0:w]
    rays = camera.ray(xs + 0.5, ys + 0.5).astype(np.float64)
    support, h0 = support_mask(P, n, ok, up, cfg)
    occ = ok & ~support
    Pf, okf = P.reshape(-1, 3), ok.ravel()
    cont = {}
    # each edge of ``_EDGE_VIEWS`` on the map's shifted views: every pair at once,
    # without gathering them (the pairs with a pixel of no geometry are computed and
    # dropped: their 0/0 is no surface's)
    for k, (ea, eb) in enumerate(_EDGE_VIEWS):
        both = ok[ea] & ok[eb]
        with np.errstate(divide="ignore", invalid="ignore"):
            cont[k] = _continuous(P[ea], n[ea], P[eb], n[eb], rays[ea], rays[eb], both, cfg).ravel()
    right = cont[0].reshape(h, w - 1)
    down = cont[1].reshape(h - 1, w)
    diag = cont[2].reshape(h - 1, w - 1)  # (y, x+1) - (y+1, x)
    idx = np.arange(h * w).reshape(h, w)
    a, b, c_, dd = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    # triangles (a, c, b) and (b, c, d): edges a-b (right top), a-c (down left), b-c (diag);
    # b-d (down right), c-d (right bottom), b-c
    t1 = right[:-1, :] & down[:, :-1] & diag
    t2 = down[:, 1:] & right[1:, :] & diag
    faces = np.concatenate([np.stack([a[t1], c_[t1], b[t1]], 1), np.stack([b[t2], c_[t2], dd[t2]], 1)])
    # occluder components: occluder pixels joined by continuous edges
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges = _edges((h, w))  # (flat pairs, in ``cont``'s order)
    ea, eb = [], []
    occf = occ.ravel()
    for k, (pa, pb) in enumerate(edges):
        m = cont[k] & occf[pa] & occf[pb]
        ea.append(pa[m])
        eb.append(pb[m])
    ea, eb = np.concatenate(ea), np.concatenate(eb)
    g = coo_matrix((np.ones(len(ea)), (ea, eb)), shape=(h * w, h * w))
    _, lab = connected_components(g, directed=False)
    uniq = np.unique(lab[occf])
    remap = np.zeros(int(lab.max()) + 1, np.int64)
    remap[uniq] = np.arange(1, len(uniq) + 1)
    labels = np.where(occf, remap[lab], 0).reshape(h, w)
    # bases: occluder pixels joined to a support pixel by a continuous edge
    supf = support.ravel()
    base = np.zeros(h * w, bool)
    for k, (pa, pb) in enumerate(edges):
        m = cont[k] & ((occf[pa] & supf[pb]) | (occf[pb] & supf[pa]))
        base[pa[m & occf[pa]]] = True
        base[pb[m & occf[pb]]] = True
    base = base.reshape(h, w)
    # casters: occluders standing on the support (a base) whose outline is, somewhere, a
    # depth discontinuity in front of a farther surface (a silhouette): an object in the
    # scene, not a wall that meets the floor in a corner and the sky at its top
    zf_ = d.ravel()
    sil = np.zeros(h * w, bool)
    for k, (pa, pb) in enumerate(edges):
        jump = okf[pa] & okf[pb] & ~cont[k]
        sil[pa[jump & occf[pa] & (zf_[pa] < zf_[pb])]] = True
        sil[pb[jump & occf[pb] & (zf_[pb] < zf_[pa])]] = True
        if k == 1 and cfg.sky_edges_cast:  # the sky above it (no geometry): a wall's top edge
            sil[pb[occf[pb] & ~(zf_[pa] > 0)]] = True
    K0 = int(labels.max())
    has_base = np.bincount(labels[base], minlength=K0 + 1) > 0
    has_sil = np.bincount(labels.ravel()[sil], minlength=K0 + 1) > 0
    is_caster = has_base & has_sil
    is_caster[0] = False
    casters = is_caster[labels]
    verts = [Pf]
    all_faces = [faces]
    # extrusion of each occluder component (module docstring)
    if occ.any():
        from zcomp_cli.worldframe import ground_frame

        right_axis = ground_frame(up)[0]
        K = int(labels.max())
        across = P @ right_axis
        lab_f = labels.ravel()
        sel = lab_f > 0
        lo = np.full(K + 1, np.inf)
        hi = np.full(K + 1, -np.inf)
        np.minimum.at(lo, lab_f[sel], across.ravel()[sel])
        np.maximum.at(hi, lab_f[sel], across.ravel()[sel])
        # along the ground, away from the camera: each pixel's ray projected on the ground
        flat = Pf - np.outer(Pf @ up, up)
        dist_h = np.linalg.norm(flat, axis=1)
        u_h = flat / np.maximum(dist_h, 1e-12)[:, None]
        nearest = np.full(K + 1, np.inf)
        np.minimum.at(nearest, lab_f[sel], dist_h[sel])
        thick = np.maximum(np.where(np.isfinite(hi - lo), hi - lo, 0.0),
                           cfg.min_thickness_rel * np.where(np.isfinite(nearest), nearest, 0.0))
        # each occluder occupies, at every height it shows, the ground distances from its
        # nearest point to its nearest point plus its width, behind its visible surface
        reach_h = np.where(sel, nearest[lab_f] + thick[lab_f], 0.0)
        back = Pf + u_h * np.maximum(reach_h - dist_h, 0.0)[:, None]
        off = h * w
        verts.append(back)
        occ_tri = np.all(occf[faces], axis=1) if len(faces) else np.zeros(0, bool)
        ft = faces[occ_tri]
        all_faces.append(ft[:, ::-1] + off)
        # side walls along the outline: edges of exactly one occluder triangle
        if len(ft):
            e = np.concatenate([ft[:, [0, 1]], ft[:, [1, 2]], ft[:, [2, 0]]])
            key = np.sort(e, 1)
            _, first, counts = np.unique(key[:, 0] * (h * w) + key[:, 1], return_index=True, return_counts=True)
            bnd = e[first[counts == 1]]
            p0, p1 = bnd[:, 0], bnd[:, 1]
            all_faces.append(np.concatenate([np.stack([p0, p1, p1 + off], 1), np.stack([p0, p1 + off, p0 + off], 1)]))
    V = np.concatenate(verts)
    F = np.concatenate(all_faces) if all_faces else np.zeros((0, 3), np.int64)
    if walls:
        wv, wf = _wall_quads(walls, up, cfg.wall_half_length)
        F = np.concatenate([F, wf + len(V)])
        V = np.concatenate([V, wv])
    return DepthMesh(vertices=V, faces=F.astype(np.int64), points=P, valid=ok, support=support, occluder=occ,
                     labels=labels, base=base, casters=casters, up=up, support_height=h0)


def _wall_quads(walls, up, half_length: float):
    """Vertices and faces of the walls beyond the frame: each a quad on its plane from
    the ground up to its top, ``half_length`` metres either side."""
    V, F = [], []
    for i, wl in enumerate(walls):
        nrm = np.asarray(wl.normal, np.float64)
        along = np.cross(up, nrm)
        along /= max(float(np.linalg.norm(along)), 1e-12)
        top = wl.top if math.isfinite(wl.top) else half_length
        B = nrm * wl.offset + up * (wl.ground - float((nrm * wl.offset) @ up))
        c = [B - half_length * along, B + half_length * along,
             B + half_length * along + top * up, B - half_length * along + top * up]
        V.extend(c)
        F.extend([[4 * i, 4 * i + 1, 4 * i + 2], [4 * i, 4 * i + 2, 4 * i + 3]])
    return np.asarray(V, np.float64), np.asarray(F, np.int64)


__all__ = ["DepthMesh", "build_depth_mesh", "support_mask", "has_geometry"]
