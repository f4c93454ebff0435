"""The light's numbers as an artist reads them: each light's direction as azimuth and
elevation in the world (``worldframe``: azimuth 0 = the camera's right, 90 = forward,
on the ground; elevation above the ground), its size, the sun/sky split, the stated
uncertainty and where each number came from (the fit's own words, ``lightparams.Origin``)."""

from __future__ import annotations

import math

import numpy as np


def light_lines(model, probe_params=None) -> list[str]:
    """Lines of text describing a ``LightModel`` (the preview sheet prints them).
    ``probe_params``: the manifest's probe (``lightparams.ProbeParams``) when given."""
    from zcomp_cli.worldframe import angles_from_direction

    up = np.asarray(model.up, np.float64)
    lines = [f"light: {'given in the manifest' if model.source == 'manifest' else 'estimated from the photograph'}"
             f"; world up {model.up_from}"]
    if probe_params is not None:
        import os

        if probe_params.is_ball:
            from zcomp_cli.chromeball import blind_degrees

            lines.append(f"probe: chrome ball {os.path.basename(probe_params.hdr)} (centre "
                         f"{probe_params.ball_center[0]:g}, {probe_params.ball_center[1]:g}, radius "
                         f"{probe_params.ball_radius:g} px, reflectance {probe_params.reflectance:g}; the "
                         f"{blind_degrees(probe_params.ball_radius):.0f} deg behind the ball filled)")
        else:
            lines.append(f"probe: {os.path.basename(probe_params.hdr)} ({probe_params.convention} convention, "
                         f"rotation {probe_params.rotation_deg:g} deg, strength {probe_params.strength:g})")
    for s in model.suns:
        az, el = angles_from_direction(s.direction, up)
        e = float(np.mean(s.irradiance))
        lines.append(f"sun: azimuth {az:.0f} deg, elevation {el:.0f} deg, radius {s.radius_deg:.2g} deg, "
                     f"irradiance {e:.3g} -- direction {s.direction_from}; size {s.radius_from}; "
                     f"strength {s.strength_from}")
    for lp in model.lamps:
        p = np.asarray(lp.position, np.float64)
        to = p - (np.zeros(3) if model.anchor is None else np.asarray(model.anchor, np.float64))
        az, el = angles_from_direction(to, up) if np.linalg.norm(to) > 0 else (float("nan"), float("nan"))
        lines.append(f"lamp: at [{p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}] m (azimuth {az:.0f}, elevation {el:.0f} deg "
                     f"from the support), radius {lp.radius_m:.2g} m -- place {lp.position_from}; strength "
                     f"{lp.strength_from}")
    sky_up = float(np.mean(model.sky.shading(up[None])[0]))
    share = model.ambient_share()
    lines.append(f"sky: shading {sky_up:.3g} on an upward surface -- {model.sky.strength_from}")
    if model.suns:
        lines.append(f"sun/sky split on the support: {100 * (1 - share):.0f}% sun, {100 * share:.0f}% sky "
                     "(a full shadow keeps the sky's share)")
    u = model.fit.uncertainty_deg
    if u is not None and math.isfinite(float(u)):
        lines.append(f"direction uncertain to {float(u):.0f} deg (RMS); shadows drawn as {model.shadows}")
    else:
        lines.append(f"shadows drawn as {model.shadows}")
    if model.fit.note:
        lines.append(f"note: {model.fit.note}")
    return lines


__all__ = ["light_lines"]
