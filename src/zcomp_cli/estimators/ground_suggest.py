"""What a photograph without maps needs, in numbers fitted to it (issue 50: the refusal
suggested ``{proxy: ground_plane, camera_height: 1.5, pitch_deg: -10}`` whatever the
photograph, and on scikit-image's coffee photograph -- a table top seen from above --
that made a 0.14 m vase a 279-pixel speck).

A ground-plane proxy fixes the scale of everything placed on it: an object ``h`` metres
tall standing at a pixel whose ray meets the floor at z-depth ``t = H_cam / -(n . r)``
(``ground_plane``) is about ``h * fy / t`` pixels tall. So for each typical view (a room
seen standing, a table top seen from above: ``VIEWS``) the camera height that makes the
manifest's object ``TARGET_SHARE`` of the frame tall there follows in closed form, and
the suggestion gives both, with the size each makes. ``object_size_note`` says when an
object's size on screen is implausible, whatever made it.
"""

from __future__ import annotations

import numpy as np

# An object placed in a photograph reads best at about this share of the frame's height
# (a vase on a table, a chair in a room: a judgement, used only to suggest a height).
TARGET_SHARE = 0.2
# Two views a photograph without maps usually shows: (words, pitch in degrees).
VIEWS = (("a room seen standing", -10.0), ("a table top or floor seen from above", -50.0))
# An object covering less than this share of the frame's pixels is a speck, more than
# this share fills it: either way its scale is likely wrong (reported, not refused).
MIN_OBJECT_SHARE = 0.002
MAX_OBJECT_SHARE = 0.8
# Where an object stands when no job says (the frame's centre, two thirds down), and how
# tall it is (metres).
DEFAULT_PIXEL_SHARE = (0.5, 2.0 / 3.0)
DEFAULT_HEIGHT_M = 0.3


def camera_height_for(camera, pixel, height_m: float, pitch_deg: float) -> float | None:
    """The camera height (metres) that makes an object ``height_m`` tall standing at
    ``pixel`` about ``TARGET_SHARE`` of the frame tall, the camera pitched by
    ``pitch_deg`` (roll 0); None where that pixel sees no floor (above the horizon)."""
    from zcomp_cli.worldframe import up_from_pitch_roll

    n = up_from_pitch_roll(pitch_deg, 0.0)
    nr = float(np.asarray(camera.ray(float(pixel[0]), float(pixel[1])), np.float64) @ n)
    if not nr < -1e-6:
        return None
    return float(height_m) * float(camera.fy) * -nr / (TARGET_SHARE * camera.height)


def ground_plane_suggestion(camera, pixel=None, height_m: float | None = None, what: str = "") -> str:
    """The suggestion for a scene without depth: per view of ``VIEWS``, the ground-plane
    line that makes its object (``height_m`` at ``pixel``, default a 0.3 m object two
    thirds down) about a fifth of the frame tall."""
    px = pixel if pixel is not None else (DEFAULT_PIXEL_SHARE[0] * camera.width, DEFAULT_PIXEL_SHARE[1] * camera.height)
    h = float(height_m) if height_m else DEFAULT_HEIGHT_M
    lines = []
    for words, pitch in VIEWS:
        hc = camera_height_for(camera, px, h, pitch)
        if hc is not None:
            lines.append(f"depth: {{proxy: ground_plane, camera_height: {hc:.2g}, pitch_deg: {pitch:g}}} for "
                         f"{words}")
    about = what or f"a {h:g} m object at pixel [{px[0]:.0f}, {px[1]:.0f}]"
    fit = (f"; each makes {about} about {TARGET_SHARE * camera.height:.0f} pixels tall "
           f"(a fifth of the frame): " + ", or ".join(lines)) if lines else ""
    return ("no depth: give a depth map file or an estimator (docs/estimation.md)" + fit
            + "; where the horizon shows, give horizon_row (its image row) in place of pitch_deg")


def object_size_note(pixels: int, frame_pixels: int, depth_m: float | None) -> str | None:
    """Why an object's size on screen is implausible (None when it is not): under
    ``MIN_OBJECT_SHARE`` of the frame a speck, over ``MAX_OBJECT_SHARE`` the frame."""
    share = pixels / max(int(frame_pixels), 1)
    far = f", {depth_m:.3g} m away" if depth_m is not None and np.isfinite(depth_m) else ""
    if share < MIN_OBJECT_SHARE:
        return (f"the object covers {pixels} pixels ({share:.2%} of the frame{far}): a speck; the scene's scale "
                "(its depth map, or a ground plane's camera_height and pitch_deg) or the object's height is "
                "likely wrong")
    if share > MAX_OBJECT_SHARE:
        return (f"the object covers {share:.0%} of the frame{far}: the scene's scale or the object's height is "
                "likely wrong")
    return None


__all__ = ["MAX_OBJECT_SHARE", "MIN_OBJECT_SHARE", "TARGET_SHARE", "VIEWS", "camera_height_for",
           "ground_plane_suggestion", "object_size_note"]
