"""Conversions between the conventions of DESIGN.md section 3, as small pure functions.

Conventions kept everywhere inside zcomp:

* images: float32 H x W x C, **linear** RGB unless a name says ``_srgb``;
* camera frame: right-handed OpenGL/Blender, x right, y up, z toward the viewer
  (the camera looks along -z);
* depth: z-depth along the optical axis in metres (positive), invalid = 0 or non-finite;
* normals: camera frame, unit vectors; a surface facing the camera has n = (0, 0, 1);
* pixels: ``[x, y] = [column, row]`` from the top-left corner, pixel centres at +0.5.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "srgb_to_linear",
    "linear_to_srgb",
    "gamma_encode",
    "luminance",
    "K_from_fov",
    "fov_from_K",
    "blender_depth_to_z_depth",
    "ray_distance_to_z_depth",
    "z_depth_to_ray_distance",
    "world_to_camera_normals",
    "normalize",
    "camera_normals_to_conditioning",
    "conditioning_to_camera_normals",
    "facing_fraction",
    "facing_problem",
    "MIN_FACING_FRACTION",
    "valid_depth_mask",
    "unit_normal_mask",
    "UNIT_NORMAL_TOL",
    "pixel_ray",
    "REC601",
    "REC709",
    "DEFAULT_SEED",
    "GAMMA",
    "SHADING_EPS",
    "SHADING_MAX",
    "WORKING_LEVEL_RANGE",
    "WORKING_LEVEL",
    "working_scale",
    "CONDITIONING_VARIANTS",
]

# Luma weights. The official ZeroComp compositor uses Rec.601 for its shadow ratio.
REC601 = np.array([0.299, 0.587, 0.114], dtype=np.float32)
REC709 = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)

# The paper's fixed seed: one latent noise for both passes of a job, and the seed of
# every deterministic random choice zcomp makes for a job.
DEFAULT_SEED = 469
# The official models read and write images gamma-2.2 encoded (not the sRGB curve).
GAMMA = 2.2
# Shading = image / max(albedo, SHADING_EPS), clamped to [SHADING_EPS, SHADING_MAX]
# (DESIGN.md section 3 and the official conditioning).
SHADING_EPS = 1e-5
SHADING_MAX = 1e3
# The photograph's working level (issue 49). The shading's clamp above and the
# compositor's ratio epsilon (1e-4) are absolute: a photograph whose radiance sits far
# from 1 -- an EXR in absolute units, 1e-6 or 1e6 -- lost its light to the clamp (its
# object drawn 1000 times too dark) or its shadow to the epsilon. A photograph whose
# median luminance lies outside WORKING_LEVEL_RANGE is worked at WORKING_LEVEL instead
# (divided by a power of two, exact in floating point) and every output is multiplied
# back (``working_scale``). The range is where neither bites: at a median luminance of
# 2^-6 the epsilon moves a shadow's ratio of 1/3 by 0.6 %, and at 2^4 a surface of
# albedo 0.02 (asphalt) shades at 800, under the clamp; the level is an LDR
# photograph's (an 18 % grey card exposed as a camera meters it). Photographs inside the
# range are worked at their own level, as before.
WORKING_LEVEL_RANGE = (2.0 ** -6, 2.0 ** 4)
WORKING_LEVEL = 0.18
# A normal this far from unit length is not one: a map's invalid pixels hold zeros or
# garbage, and a stored unit normal, even in half floats, is within 1e-3 of 1.
UNIT_NORMAL_TOL = 0.2
# ZeroComp ControlNet variants by conditioning channel count -> the maps they read, in
# channel order (DESIGN.md section 4).
CONDITIONING_VARIANTS = {
    10: ("normals", "albedo", "shading", "mask"),
    11: ("depth", "normals", "albedo", "shading", "mask"),
    13: ("depth", "normals", "albedo", "shading", "mask", "roughness", "metallic"),
}


def _as_float(x) -> np.ndarray:
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float32)
    return x


def srgb_to_linear(x_srgb) -> np.ndarray:
    """Exact sRGB (IEC 61966-2-1) decoding.

    Args:
        x_srgb: any shape, sRGB-encoded values, nominally in [0, 1]. Values are
            clipped to [0, 1] first (8/16-bit inputs cannot exceed it).
    Returns:
        Linear values in [0, 1], same shape, float32 (float64 kept).
    """
    x = np.clip(_as_float(x_srgb), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(x.dtype)


def linear_to_srgb(x_lin) -> np.ndarray:
    """Exact sRGB encoding of linear values; input clipped to [0, 1] (NaN -> 0)."""
    x = np.nan_to_num(_as_float(x_lin), nan=0.0, posinf=1.0, neginf=0.0)
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, x * 12.92, 1.055 * np.power(x, 1.0 / 2.4) - 0.055).astype(
        x.dtype
    )


def gamma_encode(x_lin, gamma: float = GAMMA) -> np.ndarray:
    """The official ZeroComp display encoding (``gamma_correction`` of its loaders):
    ``clip(x, 0, 1) ** (1 / gamma)``, a pure power law, not the sRGB curve.

    Args:
        x_lin: any shape, linear values (HDR allowed: clipped to [0, 1] first; NaN -> 0).
    Returns:
        Same shape, in [0, 1], float32 (float64 kept). ``gamma_encode(0.5) = 0.7297``.
    """
    x = np.nan_to_num(_as_float(x_lin), nan=0.0, posinf=1.0, neginf=0.0)
    return np.power(np.clip(x, 0.0, 1.0), 1.0 / gamma).astype(x.dtype)


def luminance(rgb, weights=REC601) -> np.ndarray:
    """Weighted grey of an ``(..., 3)`` array (Rec.601 luma weights by default, as the
    official ZeroComp compositor uses). Returns shape ``(...)``."""
    rgb = _as_float(rgb)
    if rgb.shape[-1] != 3:
        raise ValueError(f"luminance expects (..., 3), got {rgb.shape}")
    return rgb @ np.asarray(weights, dtype=rgb.dtype)


def K_from_fov(fov_deg: float, width: int, height: int) -> np.ndarray:
    """Pinhole intrinsics from the **horizontal** field of view, square pixels,
    principal point at the image centre (``cx = W / 2``, pixel centres at +0.5).

    Returns a float64 3x3 matrix. Raises ValueError outside 0 < fov < 180 or for a
    non-positive size.
    """
    if not (np.isfinite(fov_deg) and 0.0 < fov_deg < 180.0):
        raise ValueError(f"fov_deg must be in (0, 180), got {fov_deg}")
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    fx = (width / 2.0) / np.tan(np.radians(fov_deg) / 2.0)
    return np.array([[fx, 0.0, width / 2.0], [0.0, fx, height / 2.0], [0.0, 0.0, 1.0]])


def fov_from_K(K, width: int) -> float:
    """Horizontal field of view in degrees of intrinsics ``K`` for an image ``width`` wide."""
    K = np.asarray(K, dtype=np.float64)
    return float(np.degrees(2.0 * np.arctan((width / 2.0) / K[0, 0])))


def valid_depth_mask(depth) -> np.ndarray:
    """True where a z-depth is usable: finite and > 0."""
    depth = np.asarray(depth)
    with np.errstate(invalid="ignore"):
        return np.isfinite(depth) & (depth > 0)


def unit_normal_mask(normals) -> np.ndarray:
    """(..., ) bool: where ``normals`` (..., 3) hold a unit vector (within
    ``UNIT_NORMAL_TOL`` of length 1; NaN is none)."""
    n = np.asarray(normals, np.float64)
    return np.abs(np.sqrt(np.einsum("...c,...c->...", n, n)) - 1.0) < UNIT_NORMAL_TOL


def blender_depth_to_z_depth(z_pass, far: float = 1e9) -> np.ndarray:
    """Blender's Z pass is z-depth with 1e10 on empty pixels: map those (and anything
    non-finite, negative or beyond ``far``) to 0, the invalid value. float32 out."""
    z = np.asarray(z_pass, dtype=np.float32)
    out = np.where(valid_depth_mask(z) & (z < far), z, 0.0)
    return out.astype(np.float32)


def pixel_ray(K, x, y) -> np.ndarray:
    """The camera-frame ray through the image point ``[x, y]`` (continuous pixel
    coordinates from the top-left corner: the centre of pixel ``(col, row)`` is
    ``(col + 0.5, row + 0.5)``), scaled to z = -1 (OpenGL: the camera looks along -z, y up).

    This is the one place zcomp writes ``((x - cx) / fx, -(y - cy) / fy, -1)``.

    Args:
        K: 3x3 intrinsics.
        x, y: broadcastable arrays (or scalars) of image coordinates.
    Returns:
        (..., 3) float64; multiplying by a z-depth gives the camera-frame point.
    """
    K = np.asarray(K, dtype=np.float64)
    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    return np.stack([(x - K[0, 2]) / K[0, 0], -(y - K[1, 2]) / K[1, 1], -np.ones_like(x)], axis=-1)


def _pixel_rays(K, width: int, height: int) -> np.ndarray:
    """Rays through every pixel centre, (H, W, 3), z = -1."""
    uu, vv = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    return pixel_ray(K, uu, vv)


def ray_distance_to_z_depth(dist, K) -> np.ndarray:
    """Euclidean distance from the camera centre -> z-depth along the optical axis.

    Args:
        dist: (H, W) distances in metres; invalid (0/non-finite) stays 0.
        K: 3x3 intrinsics of that image.
    """
    dist = np.asarray(dist, dtype=np.float32)
    h, w = dist.shape
    norm = np.linalg.norm(_pixel_rays(K, w, h), axis=-1)
    out = np.where(valid_depth_mask(dist), dist / norm, 0.0)
    return out.astype(np.float32)


def z_depth_to_ray_distance(depth, K) -> np.ndarray:
    """Inverse of :func:`ray_distance_to_z_depth`."""
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    norm = np.linalg.norm(_pixel_rays(K, w, h), axis=-1)
    out = np.where(valid_depth_mask(depth), depth * norm, 0.0)
    return out.astype(np.float32)


def normalize(v, axis: int = -1, eps: float = 1e-12) -> np.ndarray:
    """Unit vectors along ``axis``; zero or non-finite vectors become 0."""
    v = np.nan_to_num(np.asarray(v, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return np.where(n > eps, v / np.maximum(n, eps), 0.0).astype(np.float32)


def world_to_camera_normals(normals_world, cam_to_world) -> np.ndarray:
    """Rotate world-space normals (e.g. Blender's Normal pass) into the camera frame.

    Args:
        normals_world: (..., 3) world-space normals.
        cam_to_world: 4x4 (or 3x3) camera-to-world matrix of a Blender camera (its
            ``matrix_world``); only the rotation is used (scale removed).
    Returns:
        (..., 3) unit camera-frame normals (OpenGL: a face toward the camera is +z);
        zero-length input normals stay 0.
    """
    M = np.asarray(cam_to_world, dtype=np.float64)[:3, :3]
    # Remove any scale of the camera object: orthonormalise via SVD.
    u, _, vt = np.linalg.svd(M)
    R = u @ vt
    n = np.asarray(normals_world, dtype=np.float64)
    # world->camera rotation is R^T; for row vectors: n_cam = n_world @ R
    return normalize(n @ R)


def camera_normals_to_conditioning(normals_cam) -> np.ndarray:
    """Camera-frame (OpenGL) unit normals -> the official ZeroComp conditioning encoding
    ``n * 0.5 + 0.5`` (DESIGN.md section 4), with **no axis flip**: zcomp's camera frame is
    already the OpenGL frame the checkpoints were trained on, so a surface facing the camera
    (n = (0, 0, 1)) encodes as (0.5, 0.5, 1.0), "blue".

    (The official code negates z only because it reads Blender's shader camera space,
    x right, y up, z forward; OpenRooms stores (N.U, N.V, N.(-W)), W = lookat - eye,
    which is this frame.)

    Args:
        normals_cam: (..., 3) camera-frame normals, components in [-1, 1].
    Returns:
        (..., 3) float32 in [0, 1] for unit input; zero (unknown) normals encode as 0.5.
    """
    return np.asarray(normals_cam, dtype=np.float32) * 0.5 + 0.5


def conditioning_to_camera_normals(encoded) -> np.ndarray:
    """Inverse of :func:`camera_normals_to_conditioning`: ``normalize(2 * e - 1)``.

    Args:
        encoded: (..., 3) values in [0, 1] (e.g. an 8-bit OpenRooms normal PNG / 255).
    Returns:
        (..., 3) float32 unit camera-frame normals; (0.5, 0.5, 0.5) (zero vector) stays 0.
    """
    return normalize(2.0 * np.asarray(encoded, dtype=np.float32) - 1.0)


# The front-facing check: a visible surface faces the camera. Below this fraction of an
# object's (or a background's) pixels the normals are in another frame than assumed.
MIN_FACING_FRACTION = 0.5


def facing_fraction(normals, K, select=None) -> float:
    """Fraction of the selected pixels whose normal faces the camera (``n . ray < 0``,
    the ray through the pixel centre); pixels with a zero normal are not counted.
    NaN when nothing is counted.

    Args:
        normals: (H, W, 3) camera-frame normals.
        K: 3x3 intrinsics of that image.
        select: optional (H, W) bool.
    """
    n = np.asarray(normals, np.float64)
    h, w = n.shape[:2]
    uu, vv = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = pixel_ray(K, uu, vv)
    use = np.linalg.norm(n, axis=-1) > 0.5
    if select is not None:
        use &= np.asarray(select, bool)
    if not use.any():
        return float("nan")
    return float(((n * rays).sum(-1)[use] < 0).mean())


def facing_problem(normals, K, select=None) -> str | None:
    """Why a camera-frame normal map cannot be zcomp's (None when it can): most of its
    normals face away from the camera (a visible surface cannot), so it is in another
    frame. The built-in renderers shade such a map into radiance of millions."""
    facing = facing_fraction(normals, K, select)
    if not facing < MIN_FACING_FRACTION:  # (NaN: no normal to judge by)
        return None
    return (f"the normals face away from the camera at {1 - facing:.0%} of the pixels: the map is in another "
            "frame than zcomp's (OpenGL camera frame: x right, y up, z toward the viewer, so a surface facing "
            "the camera has n = (0, 0, 1)); a map with z forward (Blender's shader camera space) needs its z "
            "negated, one in OpenCV's frame (y down, z forward) its y and z")


def working_scale(image) -> float:
    """The power of two a photograph is divided by to be worked at ``WORKING_LEVEL``
    (the comment of ``WORKING_LEVEL_RANGE``): 1.0 when the median luminance of its
    finite positive pixels lies in ``WORKING_LEVEL_RANGE`` (or none is positive), else
    ``2 ** round(log2(median / WORKING_LEVEL))``, its exponent within float32's normal
    range (-126 to 127: a photograph of 3e38 asked for 2^130, which float32 holds as inf).

    Args:
        image: (H, W, 3) linear RGB.
    """
    img = np.asarray(image, np.float64)
    lum = img.reshape(-1, 3) @ REC601.astype(np.float64)
    lum = lum[np.isfinite(lum) & (lum > 0)]
    if lum.size == 0:
        return 1.0
    level = float(np.median(lum))
    lo, hi = WORKING_LEVEL_RANGE
    if lo <= level <= hi:
        return 1.0
    return float(2.0 ** min(127, max(-126, round(np.log2(level / WORKING_LEVEL)))))
