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

from zcomp_cli.threads import compute_threads, in_pool, map_over

# Rays per call to the intersector: bounds the temporary arrays (float32 x 3 x 2 + the
# result: ~30 MB at 1M rays).
RAY_CHUNK = 1 << 20
# Fewest rays worth a thread of their own: embreex releases the GIL while it traces, so
# a large query splits over the cores (2 threads on 2 cores: 0.029 -> 0.014 s for 400k
# rays); under ~16k rays a thread's start-up costs more than it saves.
MIN_THREAD_RAYS = 1 << 14
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

    @staticmethod
    def _unit(dirs) -> tuple[np.ndarray, np.ndarray]:
        """(M, 3) unit directions (float64) and (M,) their validity (finite, non-zero) of
        ``dirs`` (M, 3) or (3,). Each row is divided by its own length, so a direction
        shared by many rays is normalised once, to the same bits as row by row."""
        d = np.asarray(dirs, np.float64).reshape(-1, 3)
        with np.errstate(invalid="ignore", over="ignore"):
            n2 = np.einsum("ij,ij->i", d, d)
            good = np.isfinite(d[:, 0] + d[:, 1] + d[:, 2]) & (n2 > 1e-24)
        # unit directions: distances and ``tmax`` in metres whatever the length given
        # (Embree measures them in units of the direction's length)
        return d / np.sqrt(np.where(good, n2, 1.0))[:, None], good

    @staticmethod
    def _finite_rows(o: np.ndarray) -> np.ndarray:
        """(N,) the rows of ``o`` (N, 3) with no NaN or Inf (a sum by columns: a row
        reduction of width 3 costs numpy several times as much)."""
        with np.errstate(invalid="ignore", over="ignore"):
            return np.isfinite(o[:, 0] + o[:, 1] + o[:, 2])

    def _prepare(self, origins, dirs, tmax):
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d, good_d = self._unit(dirs)
        if len(d) == 1 and len(o) != 1:  # one direction for all the rays
            d, good_d = np.broadcast_to(d, o.shape), np.broadcast_to(good_d, (len(o),))
        elif len(d) != len(o):
            raise ValueError(f"RayCaster: {len(o)} origins but {len(d)} directions")
        t = np.full(len(o), np.inf) if tmax is None else np.broadcast_to(np.asarray(tmax, np.float64), (len(o),))
        good = self._finite_rows(o) & good_d & (t > 0)
        return o, d, t, good

    @staticmethod
    def _threads_for(rays: int) -> int:
        """Threads a query of ``rays`` rays splits over: ``threads.compute_threads``, at
        most one per ``MIN_THREAD_RAYS`` rays, and only its own inside the pool
        (``threads.in_pool``)."""
        return 1 if in_pool() else min(compute_threads(), max(1, rays // MIN_THREAD_RAYS))

    def _run(self, o32: np.ndarray, d32: np.ndarray, t32: np.ndarray | None, query: str,
             split: bool = True) -> np.ndarray:
        """Embree's answers (``query`` OCCLUDED: -1 where free; DISTANCE: the first hit's
        distance) for float32 rays ``o32``, ``d32`` (n, 3) within ``t32`` (n,) (None: any
        distance), in parts of at most ``RAY_CHUNK`` rays, over ``_threads_for`` threads
        where ``split`` (else on this one; each ray's answer is its own: the split changes
        no answer)."""
        n = len(o32)
        threads = self._threads_for(n) if split else 1
        step = min(RAY_CHUNK, -(-n // (2 * threads if threads > 1 else 1)))  # two parts per thread, taken in turn
        parts = [slice(s, min(n, s + step)) for s in range(0, n, step)]

        def one(j):
            kw = {} if t32 is None and query == "DISTANCE" else \
                {"dists": np.full(j.stop - j.start, _FAR, np.float32) if t32 is None else t32[j]}
            return np.asarray(self._scene.run(o32[j], d32[j], query=query, **kw))

        res = [one(j) for j in parts] if threads == 1 else map_over(one, parts)
        return np.concatenate(res) if res else np.zeros(0)

    def occluded(self, origins, dirs, tmax=None) -> np.ndarray:
        """(N,) bool: a surface lies along each ray (origins (N, 3), unit ``dirs`` (N, 3)
        or (3,)) closer than ``tmax`` ((N,) or a number, metres; None: any distance).
        Non-finite rays are never occluded."""
        o, d, t, good = self._prepare(origins, dirs, tmax)
        out = np.zeros(len(o), bool)
        if self.backend == "none" or not good.any():
            return out
        if self.backend == "embree":
            idx = None if good.all() else np.flatnonzero(good)
            pick = (lambda a: a) if idx is None else (lambda a: a[idx])
            t32 = None if tmax is None else np.minimum(pick(t), _FAR).astype(np.float32)
            r = self._run(np.ascontiguousarray(pick(o), np.float32), np.ascontiguousarray(pick(d), np.float32), t32,
                          "OCCLUDED") != -1
            if idx is None:
                return r
            out[idx] = r
            return out
        idx = np.flatnonzero(good)
        dist = self.hit_distance(o[idx], d[idx])
        out[idx] = dist < t[idx]
        return out

    def occluded_grid(self, origins, dirs, live=None) -> np.ndarray:
        """(K, N) bool: ``occluded(origins[n], dirs[k])`` for every direction ``dirs``
        (K, 3) and origin ``origins`` (N, 3), at any distance; only where ``live`` (K, N)
        bool is set (False elsewhere, no ray traced). The same answers as ``occluded`` on
        the K x N rays, without building and normalising them one by one."""
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d, good_d = self._unit(dirs)
        mask = good_d[:, None] & self._finite_rows(o)[None, :]
        if live is not None:
            mask &= np.asarray(live, bool).reshape(len(d), len(o))
        out = np.zeros((len(d), len(o)), bool)
        if self.backend == "none" or not mask.any():
            return out
        if self.backend != "embree":
            kk, nn = np.nonzero(mask)
            out[kk, nn] = self.occluded(o[nn], d[kk])
            return out
        o32, d32 = o.astype(np.float32), d.astype(np.float32)
        n = len(o)

        def part(k: slice):  # the rays of directions k, built and traced in one thread
            m = mask[k]
            if m.all():
                out[k] = self._run(np.tile(o32, (k.stop - k.start, 1)), np.repeat(d32[k], n, 0), None, "OCCLUDED",
                                   split=False).reshape(-1, n) != -1
            elif m.any():
                kk, nn = np.nonzero(m)
                out[k.start + kk, nn] = self._run(o32[nn], d32[k.start + kk], None, "OCCLUDED", split=False) != -1

        # parts of whole directions, two per thread, taken in turn (the building of the rays
        # splits too)
        threads = min(self._threads_for(int(mask.sum())), len(d))
        step = -(-len(d) // min(len(d), 2 * threads)) if threads > 1 else len(d)
        map_over(part, [slice(k0, min(len(d), k0 + step)) for k0 in range(0, len(d), step)])
        return out

    def hit_distance(self, origins, dirs) -> np.ndarray:
        """(N,) distance to the first surface along each ray (inf where none)."""
        o, d, _, good = self._prepare(origins, dirs, None)
        out = np.full(len(o), np.inf)
        if self.backend == "none" or not good.any():
            return out
        idx = np.flatnonzero(good)
        if self.backend == "embree":
            r = self._run(np.ascontiguousarray(o[idx], np.float32), np.ascontiguousarray(d[idx], np.float32), None,
                          "DISTANCE").astype(np.float64)
            out[idx] = np.where(r < _FAR, r, np.inf)
            return out
        dn = d[idx] / np.linalg.norm(d[idx], axis=1, keepdims=True)
        loc, ray, _ = self._mesh.ray.intersects_location(o[idx], dn, multiple_hits=False)
        if len(ray):
            out[idx[ray]] = np.linalg.norm(loc - o[idx][ray], axis=1)
        return out


__all__ = ["RayCaster", "embree_available", "RAY_CHUNK", "MIN_THREAD_RAYS"]
