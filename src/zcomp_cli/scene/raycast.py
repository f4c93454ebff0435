"""Shadow rays against a triangle mesh on a real ray tracer (Embree, through ``embreex``).

``RayCaster(vertices, faces)`` builds Embree's acceleration structure once; ``occluded``
answers "does anything lie along this ray within ``tmax``" for millions of rays a second,
``hit_distance`` the distance to the first surface. Where the ``embreex`` wheel is not
available (it ships for x86_64 Linux, Windows and macOS), trimesh's own ray-triangle
intersector answers the same questions, far more slowly; ``RayCaster.backend`` says which
one runs (the light's report carries it).

Geometry is float32 inside Embree: origins are offset by the caller (a bias along the
surface normal, relative to the point's depth), never by this module.
"""

from __future__ import annotations

import numpy as np

# Rays per call to the intersector: bounds the temporary arrays (float32 x 3 x 2 + the
# result: ~30 MB at 1M rays).
RAY_CHUNK = 1 << 20
# Embree's "no hit" distance is 1e37; anything beyond this is a miss.
_FAR = 1e30


def embree_available() -> bool:
    try:
        import embreex  # noqa: F401
    except ImportError:
        return False
    return True


class RayCaster:
    """Occlusion and first-hit queries against the triangles ``vertices[faces]``.

    Args:
        vertices: (V, 3) float, camera frame, metres.
        faces: (F, 3) int indices into ``vertices``. An empty mesh occludes nothing.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        v = np.asarray(vertices, np.float64).reshape(-1, 3)
        f = np.asarray(faces, np.int64).reshape(-1, 3)
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise ValueError("RayCaster: face indices out of range")
        # a face with a non-finite corner is dropped (an indexed mesh keeps its vertices)
        f = f[np.all(np.isfinite(v[f]), axis=(1, 2))] if len(f) else f
        self.n_faces = len(f)
        self._scene = None
        self._mesh = None
        if self.n_faces == 0:
            self.backend = "none"
            return
        used, inv = np.unique(f, return_inverse=True)
        vv, ff = v[used], inv.reshape(-1, 3)
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
        except ImportError:
            import trimesh

            self._mesh = trimesh.Trimesh(vv, ff, process=False)
            self.backend = "trimesh"
            return
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self._scene, np.ascontiguousarray(vv, np.float32), np.ascontiguousarray(ff, np.int32))
        self.backend = "embree"

    def _prepare(self, origins, dirs, tmax):
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d = np.broadcast_to(np.asarray(dirs, np.float64), o.shape)
        t = np.full(len(o), np.inf) if tmax is None else np.broadcast_to(np.asarray(tmax, np.float64), (len(o),))
        with np.errstate(invalid="ignore", over="ignore"):
            n2 = np.einsum("ij,ij->i", d, d)
            good = np.isfinite(o.sum(1) + d.sum(1)) & (n2 > 1e-24) & (t > 0)
        # unit directions: distances and ``tmax`` in metres whatever the length given
        # (Embree measures them in units of the direction's length)
        d = d / np.sqrt(np.where(good, n2, 1.0))[:, None]
        return o, d, t, good

    def occluded(self, origins, dirs, tmax=None) -> np.ndarray:
        """(N,) bool: a surface lies along each ray (origins (N, 3), unit ``dirs`` (N, 3)
        or (3,)) closer than ``tmax`` ((N,) or a number, metres; None: any distance).
        Non-finite rays are never occluded."""
        o, d, t, good = self._prepare(origins, dirs, tmax)
        out = np.zeros(len(o), bool)
        if self.backend == "none" or not good.any():
            return out
        if self.backend == "embree":
            all_good = bool(good.all())
            idx = None if all_good else np.flatnonzero(good)
            n = len(o) if all_good else len(idx)
            for s in range(0, n, RAY_CHUNK):
                j = slice(s, min(n, s + RAY_CHUNK)) if all_good else idx[s:s + RAY_CHUNK]
                tf = np.minimum(t[j], _FAR).astype(np.float32)
                r = self._scene.run(o[j].astype(np.float32), d[j].astype(np.float32), dists=tf, query="OCCLUDED")
                out[j] = np.asarray(r) != -1
            return out
        idx = np.flatnonzero(good)
        dist = self.hit_distance(o[idx], d[idx])
        out[idx] = dist < t[idx]
        return out

    def hit_distance(self, origins, dirs) -> np.ndarray:
        """(N,) distance to the first surface along each ray (inf where none)."""
        o, d, _, good = self._prepare(origins, dirs, None)
        out = np.full(len(o), np.inf)
        if self.backend == "none" or not good.any():
            return out
        idx = np.flatnonzero(good)
        if self.backend == "embree":
            for s in range(0, len(idx), RAY_CHUNK):
                j = idx[s:s + RAY_CHUNK]
                r = np.asarray(self._scene.run(o[j].astype(np.float32), d[j].astype(np.float32), query="DISTANCE"),
                               np.float64)
                out[j] = np.where(r < _FAR, r, np.inf)
            return out
        dn = d[idx] / np.linalg.norm(d[idx], axis=1, keepdims=True)
        loc, ray, _ = self._mesh.ray.intersects_location(o[idx], dn, multiple_hits=False)
        if len(ray):
            out[idx[ray]] = np.linalg.norm(loc - o[idx][ray], axis=1)
        return out


__all__ = ["RayCaster", "embree_available", "RAY_CHUNK"]
