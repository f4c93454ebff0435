"""A model's output in its own conventions -> zcomp's (DESIGN.md section 3), once, at the
edge, before anything else sees it. Pure functions on numpy arrays.

* Normals: each model has a frame (which image direction its x, y and z point to) and a
  range (signed [-1, 1], or an image-style [0, 1] encoding). ``to_camera_normals``
  turns them into zcomp's camera frame: x right, y up, z toward the viewer, unit length.
  Marigold (and the models fine-tuned from it) already predicts that frame
  (``MarigoldImageProcessor.visualize_normals``: "x right, y top, z facing the
  observer"), signed: its conversion is the identity up to renormalisation.
* Intrinsic maps (albedo, material): a prediction space, ``gamma`` (what Marigold's
  target_properties call "srgb": its trainer encodes linear ground truth with
  ``x ** (1 / 2.2)``, not the IEC curve), ``srgb`` (the exact IEC 61966-2-1 curve) or
  ``linear``; ``to_linear`` decodes to linear [0, 1].
* Non-finite values (an fp16 overflow) are never passed on: ``clean_nonfinite`` fills a
  few from their nearest finite neighbour and refuses a map with more.
"""

from __future__ import annotations

import numpy as np

from zcomp_cli.conventions import GAMMA, srgb_to_linear
from zcomp_cli.errors import InputError, NumericalError

__all__ = ["NORMAL_FRAMES", "parse_normal_frame", "to_camera_normals", "INTRINSIC_SPACES",
           "to_linear", "clean_nonfinite", "MAX_NONFINITE_FRACTION"]

# Each frame: for zcomp's x, y and z, (index of the model's component, sign).
NORMAL_FRAMES: dict[str, tuple[tuple[int, int], ...]] = {
    # x right, y up, z toward the viewer: OpenGL / Blender camera, Marigold, zcomp itself.
    "opengl": ((0, 1), (1, 1), (2, 1)),
    # x right, y down, z away from the viewer (into the scene): OpenCV / COLMAP cameras.
    "opencv": ((0, 1), (1, -1), (2, -1)),
}
# More than this fraction of non-finite pixels and a map is refused, not repaired.
MAX_NONFINITE_FRACTION = 0.01
INTRINSIC_SPACES = ("linear", "gamma", "srgb")


def parse_normal_frame(value) -> tuple[tuple[int, int], ...]:
    """A frame name from :data:`NORMAL_FRAMES`, or three signed axis names saying what
    zcomp's x, y and z are in the model's components, e.g. ``['x', '-y', '-z']`` (OpenCV).

    Raises:
        InputError: not a known name, or not a permutation of x, y, z with signs.
    """
    if isinstance(value, str):
        if value in NORMAL_FRAMES:
            return NORMAL_FRAMES[value]
        raise InputError(f"unknown normals frame {value!r}: use {', '.join(NORMAL_FRAMES)} "
                         "or three signed axes such as [x, -y, -z]")
    if not (isinstance(value, (list, tuple)) and len(value) == 3 and all(isinstance(a, str) for a in value)):
        raise InputError(f"normals frame must be a name or three signed axes such as [x, -y, -z], got {value!r}")
    out = []
    for a in value:
        a = a.strip().lower()
        sign = -1 if a.startswith("-") else 1
        name = a.lstrip("+-")
        if name not in ("x", "y", "z"):
            raise InputError(f"normals frame axis {a!r}: expected x, y or z with an optional sign")
        out.append(("xyz".index(name), sign))
    if sorted(i for i, _ in out) != [0, 1, 2]:
        raise InputError(f"normals frame {list(value)} must use each of x, y and z once")
    return tuple(out)


def to_camera_normals(pred, frame=NORMAL_FRAMES["opengl"], *, encoded: bool = False,
                      min_norm: float = 1e-3) -> np.ndarray:
    """A model's normal map -> zcomp camera-frame unit normals.

    Args:
        pred: (H, W, 3) float, the model's normals: signed components in [-1, 1], or
            ``encoded`` in [0, 1] (``n * 0.5 + 0.5``, as in an RGB normal image).
        frame: a parsed frame (:func:`parse_normal_frame`) or a name of one.
        encoded: the values are ``n * 0.5 + 0.5``.
        min_norm: vectors shorter than this (after decoding) carry no direction.
    Returns:
        (H, W, 3) float32 unit vectors in zcomp's camera frame (x right, y up, z toward
        the viewer); 0 where the prediction is non-finite or shorter than ``min_norm``.
    """
    p = np.asarray(pred, dtype=np.float64)
    if p.ndim != 3 or p.shape[-1] != 3:
        raise InputError(f"normals prediction must be (H, W, 3), got {p.shape}")
    axes = parse_normal_frame(frame) if isinstance(frame, (str, list)) else frame
    if encoded:
        p = p * 2.0 - 1.0
    n = np.stack([sign * p[..., i] for i, sign in axes], axis=-1)
    finite = np.isfinite(n).all(axis=-1)
    n = np.where(finite[..., None], n, 0.0)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    ok = finite & (norm[..., 0] >= min_norm)
    return np.where(ok[..., None], n / np.where(ok[..., None], norm, 1.0), 0.0).astype(np.float32)


def to_linear(pred, space: str) -> np.ndarray:
    """An intrinsic map in ``space`` (see :data:`INTRINSIC_SPACES`) -> linear [0, 1].

    Args:
        pred: any shape, values nominally in [0, 1] (clipped first; NaN is kept for
            :func:`clean_nonfinite` to see).
        space: ``linear`` (returned clipped), ``gamma`` (``x ** 2.2``, Marigold's
            "srgb") or ``srgb`` (the exact IEC curve).
    Returns:
        float32 array of the same shape, linear, in [0, 1] (NaN where the input was).
    """
    if space not in INTRINSIC_SPACES:
        raise InputError(f"unknown prediction space {space!r}: use {', '.join(INTRINSIC_SPACES)}")
    x = np.asarray(pred, dtype=np.float32)
    nan = np.isnan(x)
    x = np.clip(np.nan_to_num(x, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    if space == "gamma":
        x = x ** np.float32(GAMMA)
    elif space == "srgb":
        x = srgb_to_linear(x)
    return np.where(nan, np.nan, x).astype(np.float32)


def clean_nonfinite(arr, what: str, *, max_fraction: float = MAX_NONFINITE_FRACTION,
                    hint: str = "") -> tuple[np.ndarray, str | None]:
    """Fill the non-finite pixels of a model output from their nearest finite pixel, or
    refuse the map when more than ``max_fraction`` of its pixels are non-finite.

    Args:
        arr: (H, W) or (H, W, C) float; a pixel is bad if any of its channels is NaN/Inf.
        what: the map's name, for the messages.
        max_fraction: the largest fraction of bad pixels that is repaired.
        hint: appended to the refusal (e.g. "run it in fp32 or bf16").
    Returns:
        (a float32 copy with every pixel finite, a note saying how many were filled, or
        None when nothing was).
    Raises:
        NumericalError: too many bad pixels (or all of them).
    """
    from scipy.ndimage import distance_transform_edt

    a = np.asarray(arr, dtype=np.float32)
    if a.ndim not in (2, 3) or a.size == 0:
        raise InputError(f"{what}: expected an (H, W) or (H, W, C) map, got {a.shape}")
    bad = ~np.isfinite(a) if a.ndim == 2 else ~np.isfinite(a).all(axis=-1)
    n = int(bad.sum())
    if n == 0:
        return a.copy(), None
    frac = n / bad.size
    if frac > max_fraction:
        raise NumericalError(f"{what}: {n} of {bad.size} pixels ({frac:.1%}) are NaN or infinite; a "
                             f"model output with more than {max_fraction:.0%} of them is refused, not "
                             f"repaired{'; ' + hint if hint else ''}")
    idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
    out = a[tuple(idx)] if a.ndim == 2 else a[idx[0], idx[1]]
    return out.astype(np.float32), f"{what}: {n} non-finite pixels ({frac:.2%}) filled from their nearest neighbour"
