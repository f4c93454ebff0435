"""Screen-space shadow rays: march camera-frame points toward a light over a depth map."""

from __future__ import annotations

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.scene.config import MarchConfig
from zcomp_cli.scene.sampling import length


def sample_depth(depth: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear z-depth at pixel coords (x, y) (pixel centres at +0.5), ignoring invalid
    (<= 0) texels; returns 0 where less than half the weight is valid or out of frame."""
    H, W = depth.shape
    fx = x - 0.5
    fy = y - 0.5
    x0 = np.floor(fx)
    y0 = np.floor(fy)
    ax = fx - x0
    ay = fy - y0
    x0 = x0.astype(np.int64)
    y0 = y0.astype(np.int64)
    xa, xb = np.clip(x0, 0, W - 1), np.clip(x0 + 1, 0, W - 1)
    ya, yb = np.clip(y0, 0, H - 1) * W, np.clip(y0 + 1, 0, H - 1) * W
    flat = depth.reshape(-1)
    num = np.zeros_like(fx)
    den = np.zeros_like(fx)
    for idx, w in ((ya + xa, (1 - ax) * (1 - ay)), (ya + xb, ax * (1 - ay)),
                   (yb + xa, (1 - ax) * ay), (yb + xb, ax * ay)):
        d = flat[idx]
        w = w * (d > 0)
        num += w * d
        den += w
    return np.where(den >= 0.5, num / np.maximum(den, 1e-12), 0.0)


def march_visibility(points: np.ndarray, normals: np.ndarray, light_dir: np.ndarray,
                     depth: np.ndarray, camera: Camera, *, cfg: MarchConfig, steps: int,
                     max_distance_rel: float | None | str = "march", jitter: np.ndarray | None = None,
                     return_distance: bool = False, nearest: bool = False,
                     occluder_mask: np.ndarray | None = None, max_distance=None, walls=(),
                     return_texel: bool = False):
    """Binary visibility of points toward directional light(s).

    Args:
        points: (N, 3) camera-frame points (metres; z < 0 in front of the camera).
        normals: (N, 3) camera-frame unit normals (start offset along them).
        light_dir: (3,) or (N, 3) unit directions toward the light, camera frame.
        depth: (H, W) z-depth buffer (0 = invalid/sky, never occludes).
        steps: samples along each ray; spacing grows quadratically (detail near contact).
        nearest: sample the depth map at the nearest texel instead of bilinearly:
            bilinear depth across a silhouette invents a surface between the object
            and the floor, which shadows the silhouette's own pixels (dark rims).
        jitter: optional (N,) offsets in [0, 1) of the samples along each ray (in steps):
            per-pixel decorrelation turns the step pattern into noise a filter removes,
            instead of banding.
        occluder_mask: optional (H, W) bool: only texels where it is True occlude (the
            shadow of one part of the frame, such as an inserted object).
        cfg: the march's reach, bias and occluder thickness (``MarchConfig``: fractions
            of the point's own depth, scale-free).
        max_distance_rel: the ray's length as a fraction of the point's depth: "march"
            (``cfg.march_range_rel``, a shadow ray's), "sky" (``cfg.sky_range_rel``, a
            sky ray's), a number, or None (no relative limit).
        max_distance: optional (N,) or scalar ray length in metres (a lamp's distance:
            nothing beyond the light occludes it); the shorter of the two limits holds.
        walls: the scene's walls beyond the frame (``planes.Wall``): they occlude too,
            at any distance up to ``max_distance``.
    Returns:
        (N,) float64 in {0, 1}; 1 = lit. A ray leaving the frame or passing behind the
        camera counts as unoccluded from there on. With ``return_distance``, also (N,)
        the distance along the ray to the first occluder (inf where lit); with
        ``return_texel`` also (N, 2) int the (row, column) of the texel the ray first
        met in the depth map (-1 where it met none, or only a wall beyond the frame).
    """
    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64)
    l = np.broadcast_to(np.asarray(light_dir, np.float64), p.shape)
    N = len(p)
    if N == 0:
        out = (np.zeros(0),) + ((np.zeros(0),) if return_distance else ()) + (
            (np.zeros((0, 2), np.int64),) if return_texel else ())
        return out if len(out) > 1 else out[0]
    bias_rel, thickness_rel = cfg.march_bias_rel, cfg.march_thickness_rel
    if isinstance(max_distance_rel, str):
        max_distance_rel = {"march": cfg.march_range_rel, "sky": cfg.sky_range_rel}[max_distance_rel]
    z0 = np.maximum(-p[:, 2], 1e-6)
    start = p + n * (bias_rel * z0)[:, None]
    # per component, contiguous (the (N, 3) products and their strided columns cost
    # more than the arithmetic)
    sx, sy, sz = (np.ascontiguousarray(start[:, i]) for i in range(3))
    lx, ly, lz = (np.ascontiguousarray(l[:, i]) for i in range(3))
    occluded = np.zeros(N, bool)
    t_hit = np.full(N, np.inf)
    H, W = depth.shape
    dmax = np.full(N, np.inf) if max_distance_rel is None else max_distance_rel * z0
    if max_distance is not None:
        dmax = np.minimum(dmax, np.broadcast_to(np.asarray(max_distance, np.float64), (N,)))
    if not np.all(np.isfinite(dmax)):
        raise ValueError("march_visibility: give max_distance_rel or a finite max_distance")
    jit = np.zeros(N) if jitter is None else np.broadcast_to(np.asarray(jitter, np.float64) - 0.5, (N,))
    texel = np.full((N, 2), -1, np.int64) if return_texel else None
    # the rays still marching: a ray that met an occluder has its answer, and one that
    # was in the frame and is no longer never comes back in (in front of the camera its
    # image is a line, run one way, leaving a convex frame; behind it, it stays behind);
    # each step works on the others alone. A ray may start outside the frame (its start
    # lifted off a pixel at the frame's edge) and come in: it marches on.
    act = np.arange(N)
    entered = np.zeros(N, bool)
    for k in range(1, steps + 1):
        tk = dmax[act] * (np.minimum(np.maximum(k + jit[act], 0.25), steps) / steps) ** 2
        qz = -(sz[act] + lz[act] * tk)
        with np.errstate(divide="ignore", invalid="ignore"):
            zs = np.where(qz > 1e-6, qz, np.nan)
            x = camera.fx * (sx[act] + lx[act] * tk) / zs + camera.cx
            y = -camera.fy * (sy[act] + ly[act] * tk) / zs + camera.cy
        inside = np.isfinite(x) & np.isfinite(y) & (x >= 0) & (x < W) & (y >= 0) & (y < H)
        xs = np.where(inside, x, 0.5)
        ys = np.where(inside, y, 0.5)
        iy, ix = ys.astype(np.int64), xs.astype(np.int64)  # in the frame: no clip needed
        ds = depth[iy, ix] if nearest else sample_depth(depth, xs, ys)
        gap = qz - ds
        hit = inside & (ds > 0) & (gap > bias_rel * qz) & (gap < thickness_rel * np.maximum(qz, 1e-6))
        if occluder_mask is not None:
            hit &= occluder_mask[iy, ix]
        first = act[hit]
        if return_distance:
            t_hit[first] = tk[hit]
        if return_texel:
            texel[first] = np.stack([iy[hit], ix[hit]], 1)
        occluded[first] = True
        gone = hit | (~inside & entered[act])
        entered[act] |= inside
        act = act[~gone]
        if not len(act):
            break
    if walls:
        from zcomp_cli.scene.planes import walls_block

        wb, wt = walls_block(walls, p + n * (bias_rel * z0)[:, None], l, max_distance)
        t_hit = np.minimum(t_hit, wt)
        occluded |= wb
    vis = (~occluded).astype(np.float64)
    out = (vis, t_hit) if return_distance else (vis,)
    out = out + (texel,) if return_texel else out
    return out if len(out) > 1 else vis


def grid_points(d, n, valid, camera, box, step=1):
    """Pixels of ``box = (y0, x0, y1, x1)`` on a ``step`` grid: (gy, gx, camera-frame points,
    unit normals (0 where not ``valid``), valid)."""
    wy0, wx0, wy1, wx1 = box
    gy, gx = np.mgrid[wy0:wy1:step, wx0:wx1:step]
    nv = n[gy, gx].astype(np.float64)
    ok = valid[gy, gx]
    nv = np.where(ok[..., None], nv / np.maximum(length(nv), 1e-12)[..., None], 0.0)
    return gy, gx, camera.ray(gx + 0.5, gy + 0.5) * d[gy, gx][..., None], nv, ok


__all__ = ["sample_depth", "march_visibility", "grid_points"]
