"""2D objects (paper, Extensions): an image + mask stands in for a mesh.

The object is a shape proxy standing upright on the support plane at the placement
pixel: a vertical rectangle ("billboard") turned to face the camera, ``height_m`` tall
and as wide as the mask's aspect ratio says. Its RGB is the albedo (clipped to [0, 1]);
its depth is the billboard's (planar); its normals are rounded so the renderer shades it
like a solid: ``billboard`` bulges like a pillow from the mask's distance transform,
``cylinder`` like an upright cylinder (per-row horizontal profile). The footprint is a
square of the object's width on the support plane centred at the contact point.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.bundle import ObjectBundle
from zcomp_cli.camera import Camera
from zcomp_cli.conventions import valid_depth_mask
from zcomp_cli.errors import GeometryError, InputError

PROXIES = ("billboard", "cylinder")


def _support_normal_at(support_normal, support_depth, camera, px, py):
    h, w = support_depth.shape
    x0, x1 = max(0, px - 3), min(w, px + 4)
    y0, y1 = max(0, py - 3), min(h, py + 4)
    if support_normal is not None:
        n = np.asarray(support_normal, np.float64)[y0:y1, x0:x1].reshape(-1, 3)
        n = n[np.isfinite(n).all(1) & (np.linalg.norm(n, axis=1) > 0.5)]
        if len(n):
            m = np.median(n, axis=0)
            if np.linalg.norm(m) > 1e-6:
                return m / np.linalg.norm(m)
    from zcomp_cli.estimators.normals_from_depth import normals_from_depth

    n = normals_from_depth(support_depth, camera)[y0:y1, x0:x1].reshape(-1, 3).astype(np.float64)
    n = n[np.linalg.norm(n, axis=1) > 0.5]
    if not len(n):
        raise GeometryError(f"no valid support surface around pixel ({px}, {py})")
    m = np.median(n, axis=0)
    return m / np.linalg.norm(m)


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Sample img (h, w[, c]) at continuous pixel coords (u = column, v = row; centres
    at +0.5); outside -> 0."""
    import cv2

    out = cv2.remap(np.ascontiguousarray(img, np.float32), (u - 0.5).astype(np.float32),
                    (v - 0.5).astype(np.float32), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out


def object_bundle_from_image(image_lin, mask, camera: Camera, placement_pixel, height_m: float,
                             support_depth, support_normal=None, *,
                             proxy: str = "billboard") -> ObjectBundle:
    """Build an object intrinsics bundle from a 2D cut-out.

    Args:
        image_lin: (h, w, 3) linear RGB of the object (any size; used as albedo).
        mask: (h, w) coverage in [0, 1].
        camera: the scene camera (the bundle is rendered at its size).
        placement_pixel: ``[x, y]`` scene pixel where the object's base touches the support.
        height_m: object height in metres (> 0).
        support_depth: (H, W) scene z-depth (metres).
        support_normal: optional (H, W, 3) scene normals; estimated from depth if None.
        proxy: 'billboard' or 'cylinder' (the normal field).
    Returns:
        ObjectBundle at the scene's camera with meta {object_height_m, proxy, source}.
    """
    img = np.asarray(image_lin, np.float32)
    m = np.asarray(mask, np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"2D object: image must be (h, w, 3), got {img.shape}")
    if m.shape != img.shape[:2]:
        raise InputError(f"2D object: mask {m.shape} does not match the image {img.shape[:2]}")
    if proxy not in PROXIES:
        raise InputError(f"2D object: proxy must be one of {PROXIES}, got {proxy!r}")
    if not (np.isfinite(height_m) and height_m > 0):
        raise InputError(f"2D object: height must be positive metres, got {height_m!r}")
    sd = np.asarray(support_depth, np.float64)
    if sd.shape != (camera.height, camera.width):
        raise InputError(f"2D object: support depth {sd.shape} does not match the camera")
    m = np.clip(np.nan_to_num(m), 0, 1)
    img = np.clip(np.nan_to_num(img), 0, 1)
    ys, xs = np.nonzero(m > 0.5)
    if len(ys) == 0:
        raise InputError("2D object: the mask is empty")
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    img, m = img[y0:y1, x0:x1], m[y0:y1, x0:x1]
    bh, bw = m.shape

    # 1. Contact point and the billboard frame (up = support normal, facing the camera).
    px, py = float(placement_pixel[0]), float(placement_pixel[1])
    ix, iy = int(np.floor(px)), int(np.floor(py))
    if not (0 <= ix < camera.width and 0 <= iy < camera.height):
        raise GeometryError(f"placement pixel ({px}, {py}) lies outside the image")
    z0 = sd[iy, ix]
    if not valid_depth_mask(np.array([z0]))[0]:
        raise GeometryError(f"no valid support depth at placement pixel ({px}, {py})")
    up = _support_normal_at(support_normal, sd, camera, ix, iy)
    # The support plane through the point seen at the pixel centre; the contact point is
    # where the ray through the exact (sub-pixel) placement meets that plane.
    Pc = camera.pixel_rays()[iy, ix] * z0
    ray0 = camera.ray(px, py)
    den = float(ray0 @ up)
    P0 = ray0 * (float(Pc @ up) / den) if abs(den) > 1e-9 and (Pc @ up) / den > 0 else ray0 * z0
    face = -P0 - np.dot(-P0, up) * up  # toward the camera, horizontal
    if np.linalg.norm(face) < 1e-9:
        raise GeometryError("the camera looks straight down the support normal; a billboard has no facing")
    face /= np.linalg.norm(face)
    right = np.cross(up, face)
    width_m = height_m * bw / bh

    # 2. Ray-billboard intersection for every scene pixel.
    rays = camera.pixel_rays()
    denom = rays @ face
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(np.abs(denom) > 1e-12, (P0 @ face) / denom, np.nan)
    P = rays * t[..., None]
    local = P - P0
    u = (local @ right / width_m + 0.5) * bw
    v = (1.0 - local @ up / height_m) * bh
    ok = np.isfinite(t) & (t > 0)
    u = np.where(ok, u, -10.0)
    v = np.where(ok, v, -10.0)
    cov = np.clip(_bilinear(m, u, v), 0, 1)
    cov[~ok] = 0
    if not (cov > 0.5).any():
        raise GeometryError("the 2D object falls outside the image or is too small to see")
    albedo = _bilinear(img, u, v)
    inside = cov > 1e-3
    albedo = np.where(inside[..., None], albedo / np.maximum(cov, 1e-3)[..., None], 0.0)
    albedo = np.clip(albedo, 0, 1).astype(np.float32)
    depth = np.where(cov > 0.5, t, 0.0).astype(np.float32)

    # 3. Rounded normals in the billboard frame (right, up, face).
    if proxy == "cylinder":
        s = np.zeros((bh, bw), np.float32)
        cols = np.arange(bw) + 0.5
        for r in range(bh):
            c = np.nonzero(m[r] > 0.5)[0]
            if len(c):
                lo, hi = c.min(), c.max() + 1
                half = max((hi - lo) / 2, 0.5)
                s[r] = np.clip((cols - (lo + hi) / 2) / half, -1, 1)
        sx, sy = s, np.zeros_like(s)
    else:
        import cv2

        # Pad with background so a mask touching its bounding box still has an edge.
        pad = np.pad((m > 0.5).astype(np.uint8), 1)
        dt = cv2.distanceTransform(pad, cv2.DIST_L2, 5)[1:-1, 1:-1].astype(np.float64)
        rad = max(dt.max(), 1.0)
        prof = np.sqrt(np.clip(1 - (1 - np.clip(dt / rad, 0, 1)) ** 2, 0, 1))  # circular edge
        gy, gx = np.gradient(prof * rad)  # height in pixels -> slopes
        sx = np.clip(-gx, -1, 1)
        sy = np.clip(gy, -1, 1)  # rows grow downward, "up" grows upward
    sz = np.sqrt(np.clip(1 - sx ** 2 - sy ** 2, 0, 1))
    loc = np.stack([sx, sy, sz], -1).astype(np.float32)
    # sx is the outward slope: positive to the right for the cylinder; for the
    # distance-transform profile -grad points outward.
    loc_s = _bilinear(loc, u, v)
    nrm = (loc_s[..., :1] * right + loc_s[..., 1:2] * up + loc_s[..., 2:3] * face)
    ln = np.linalg.norm(nrm, axis=-1, keepdims=True)
    nrm = np.where(ln > 1e-6, nrm / np.maximum(ln, 1e-6), face)
    # A visible surface cannot face away from the camera: silhouette normals of the
    # rounded proxy are made perpendicular to the view ray instead (a real silhouette).
    view = -rays / np.linalg.norm(rays, axis=-1, keepdims=True)
    nv = np.sum(nrm * view, axis=-1, keepdims=True)
    nrm = np.where(nv < 0, nrm - nv * view, nrm)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-9)
    normals = np.where((cov > 0.5)[..., None], nrm, 0.0).astype(np.float32)

    # 4. Footprint: the support plane under the base (a width x width square).
    with np.errstate(divide="ignore", invalid="ignore"):
        tp = (P0 @ up) / (rays @ up)
    Q = rays * tp[..., None] - P0
    fp = (np.isfinite(tp) & (tp > 0) & (np.abs(Q @ right) <= width_m / 2)
          & (np.abs(Q @ face) <= width_m / 2))
    footprint = np.where(fp, tp, 0.0).astype(np.float32)

    meta = {"object_height_m": float(height_m), "proxy": proxy, "source": "image",
            "placement_pixel": [px, py], "width_m": float(width_m)}
    return ObjectBundle(depth=depth, normals=normals, albedo=albedo, mask=cov.astype(np.float32),
                        footprint_depth=footprint, camera=camera, meta=meta)
