"""The manifest's light (``pipeline/lightspec.py``) frozen in the light fit.

Each given light becomes atoms of the same solver as the estimate (``estimate``,
``solver``) with its parameters fixed:

* the lights with physical strengths -- a probe (its sources and its sky), suns with an
  ``irradiance``, lamps with a ``power`` -- add up to **one** coloured atom: their
  strengths hold relative to each other, and its one weight is the photograph's
  exposure;
* a light with ``strength``/``power: auto`` is its own grey atom: its strength and colour
  are fitted; a sun's size, when not given, is chosen among ``estimate.RADII_DEG`` by the
  held-out pixels (the default when they cannot tell);
* a sun's number ``strength`` (direct over sky, the older form) ties it to a uniform sky
  in one grey atom;
* without a probe the sky is fitted (the estimate's sky lobes).

Units (Blender's, so a scene lit in Blender can be given as it is; checked against
Cycles in the tests): a probe's radiance is shading as it is (a uniform sky of radiance
L shades a surface with L); a sun of irradiance E (W/m^2, Blender's Sun strength) gives
``E / pi`` on a surface facing it; a point lamp of power P (W) gives ``P / (4 pi^2 r^2)``
at distance r.
"""

from __future__ import annotations

import math

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.renderers.physical import atoms as at
from zcomp_cli.renderers.physical import sh
from zcomp_cli.renderers.physical.estimate import (PRIOR_RIDGE, RADII_DEG, FitLight, held_out_blocks, model_from_fit,
                                                   prepare, prior_weights, sky_atoms, tempered_likelihood)
from zcomp_cli.renderers.physical.lightmodel import FitSummary, Lamp, LightModel, Origin, ShadowKind, Sky, Sun
from zcomp_cli.renderers.physical.settings import DEFAULTS, PhysicalSettings
from zcomp_cli.renderers.physical.solver import Atom, base_sigma, fit, score_candidates

SUN_SHADING_PER_IRRADIANCE = 1.0 / math.pi
LAMP_SHADING_PER_WATT = 1.0 / (4.0 * math.pi ** 2)


def light_direction(spec: dict, frame) -> np.ndarray:
    """Camera-frame unit direction toward a sun spec (``direction``, or azimuth and
    elevation on the ground of ``frame``'s up)."""
    from zcomp_cli.worldframe import direction_from_angles

    if spec.get("direction") is not None:
        d = np.asarray(spec["direction"], np.float64)
        return d / np.linalg.norm(d)
    return direction_from_angles(spec["azimuth_deg"], spec["elevation_deg"], np.asarray(frame)[1])


def _colour(spec) -> np.ndarray:
    c = spec.get("color")
    return np.ones(3) if c is None else np.asarray(c, np.float64)


def fit_known(specs: list, depth, normals, shading, known, albedo, camera: Camera, *, up, up_from: Origin,
              settings: PhysicalSettings = DEFAULTS, seed: int = 0) -> LightModel:
    """LightModel of the manifest's lights ``specs`` (``parse_light``'s ``lights``),
    their free parameters fitted to the photograph's known shading (module docstring)."""
    from zcomp_cli.renderers.physical.probe import load_probe

    up = np.asarray(up, np.float64)
    pp = prepare(depth, normals, shading, known, albedo, camera, up, settings)
    fp = pp.fp
    steps = settings.estimate_march_steps
    n_fit = len(fp)
    fixed = np.zeros((n_fit, 3))
    fixed_parts = []  # (kind, spec, extra) to rebuild the lights once the exposure is known
    probe = None
    autos: list[tuple[dict, FitLight]] = []
    ratio_specs = []
    for spec in specs:
        t = spec["type"]
        if t == "probe":
            probe = load_probe(spec["hdr"], pp.frame, convention=spec["convention"], rotation_deg=spec["rotation_deg"])
            k = float(spec["strength"])
            if n_fit:
                fixed += k * at.sky_atom_values(fp, probe.sky_radiance_sh, pp.sky_vis)
                for src in probe.sources:
                    col = at.sun_column(fp, src.direction, src.radius_deg, steps=steps,
                                        cone_samples=settings.cone_samples, seed=seed)
                    fixed += k * col[:, None] * src.power[None] * SUN_SHADING_PER_IRRADIANCE
            fixed_parts.append(("probe", spec, probe))
        elif t == "sun":
            d = light_direction(spec, pp.frame)
            radius = spec["angular_radius_deg"]
            if settings.shadow_softness is not None:
                radius = float(settings.shadow_softness)
            if spec.get("irradiance") is not None:
                r = radius if radius is not None else _default_sun_radius()
                if n_fit:
                    col = at.sun_column(fp, d, r, steps=steps, cone_samples=settings.cone_samples, seed=seed)
                    fixed += (spec["irradiance"] * SUN_SHADING_PER_IRRADIANCE) * col[:, None] * _colour(spec)[None]
                fixed_parts.append(("sun", spec, (d, r)))
            elif spec["strength"] == "auto":
                autos.append((spec, FitLight("sun", d, -1.0 if radius is None else float(radius), np.zeros(n_fit),
                                           Origin.FIT if radius is None else Origin.MANIFEST)))
            else:
                ratio_specs.append((spec, d, radius if radius is not None else _default_sun_radius()))
        else:  # lamp
            q = np.asarray(spec["position"], np.float64)
            rm = spec["radius_m"] if spec["radius_m"] is not None else _default_lamp_radius()
            facing = None if spec.get("facing") is None else np.asarray(spec["facing"], np.float64)
            if spec["power"] != "auto":
                if n_fit:
                    col = _lamp_column(fp, q, rm, facing, steps, settings.cone_samples, seed)
                    fixed += (spec["power"] * LAMP_SHADING_PER_WATT) * col[:, None] * _colour(spec)[None]
                fixed_parts.append(("lamp", spec, (q, rm, facing)))
            else:
                light = FitLight("lamp", q, float(rm), _lamp_column(fp, q, rm, facing, steps, settings.cone_samples, seed)
                               if n_fit else np.zeros(0),
                               Origin.MANIFEST if spec["radius_m"] is not None else Origin.DEFAULT)
                light.facing = facing
                autos.append((spec, light))
    note = ""
    if n_fit < 3:
        return _unfitted(pp, specs, fixed_parts, autos, ratio_specs, up, up_from,
                         f"too few known pixels with geometry ({n_fit}) to fit the light's strength")
    # a probe is the whole sky; without one the sky is fitted
    atoms = [] if probe is not None else sky_atoms(pp)
    if ratio_specs:
        # the older form: sun / sky fixed, one grey atom with a uniform sky
        lobe = dict(at.sky_lobes(pp.frame))["sky"]
        unit_sky = at.sky_atom_values(fp, lobe, pp.sky_vis)
        unit_up = max(float(sh.evaluate(sh.shading_coeffs(lobe[:, None]), up[None])[0, 0]), 1e-9)
        comp = unit_sky / unit_up
        for spec, d, r in ratio_specs:
            comp = comp + float(spec["strength"]) * at.sun_column(fp, d, r, steps=steps,
                                                                  cone_samples=settings.cone_samples, seed=seed)
        atoms = [a for a in atoms if not a.name.startswith("sky")] + [Atom("ratio", comp)]
    if fixed_parts:
        atoms.append(Atom("fixed", fixed))
    # the auto lights: their size among RADII_DEG where not given, by the held-out pixels
    names = []
    for i, (spec, light) in enumerate(autos):
        if light.kind == "sun":
            _fit_radius(pp, light, [a.values for a in atoms] + [x.column for _, x in autos[:i]], settings, seed)
        atoms.append(Atom(f"light{i}", light.column))
        names.append(f"light{i}")
    res = fit(atoms, pp.shading, train=fp.train, prior=prior_weights(atoms, pp, names), ridge=PRIOR_RIDGE,
              direct=names + (["fixed"] if fixed_parts else []) + (["ratio"] if ratio_specs else []))
    k = float(np.mean(res.weights.get("fixed", np.zeros(3)))) if fixed_parts else 1.0
    summary = FitSummary(residual=float(res.loss_train), pixels=n_fit, note=note,
                         exposure=k if fixed_parts else float("nan"))
    model = model_from_fit(pp, res, [x for _, x in autos], names, up, up_from, summary, origin=Origin.MANIFEST,
                   source="manifest")
    suns = list(model.suns)
    facings = [getattr(x, "facing", None) for _, x in autos if x.kind == "lamp"]
    lamps = [_with_facing(lp, f) for lp, f in zip(model.lamps, facings)]
    extra_sh = np.zeros((sh.N_COEFFS, 3))
    gloss_probe = None
    for kind, spec, extra in fixed_parts:
        if kind == "probe":
            s = k * float(spec["strength"])
            extra_sh += s * extra.sky_radiance_sh
            for src in extra.sources:
                suns.append(Sun(direction=src.direction, radius_deg=src.radius_deg,
                                irradiance=s * src.power * SUN_SHADING_PER_IRRADIANCE,
                                direction_from=Origin.PROBE, radius_from=Origin.PROBE, strength_from=Origin.PROBE))
            gloss_probe = extra.gloss.scaled(s)
        elif kind == "sun":
            d, r = extra
            suns.append(Sun(direction=d, radius_deg=r, irradiance=k * spec["irradiance"] * SUN_SHADING_PER_IRRADIANCE
                            * _colour(spec), direction_from=Origin.MANIFEST,
                            radius_from=Origin.MANIFEST if spec["angular_radius_deg"] is not None else Origin.DEFAULT,
                            strength_from=Origin.MANIFEST))
        else:
            q, rm, facing = extra
            lamps.append(Lamp(position=q, radius_m=rm, intensity=k * spec["power"] * LAMP_SHADING_PER_WATT
                              * _colour(spec), facing=facing, position_from=Origin.MANIFEST,
                              radius_from=Origin.MANIFEST if spec["radius_m"] is not None else Origin.DEFAULT,
                              strength_from=Origin.MANIFEST))
    sky_sh = model.sky.radiance_sh + extra_sh
    if ratio_specs:
        w = np.asarray(res.weights["ratio"])
        lobe = dict(at.sky_lobes(pp.frame))["sky"]
        unit_up = max(float(sh.evaluate(sh.shading_coeffs(lobe[:, None]), up[None])[0, 0]), 1e-9)
        sky_sh = sky_sh + lobe[:, None] * (w / unit_up)[None]
        for spec, d, r in ratio_specs:
            suns.append(Sun(direction=d, radius_deg=r, irradiance=w * float(spec["strength"]),
                            direction_from=Origin.MANIFEST,
                            radius_from=Origin.MANIFEST if spec["angular_radius_deg"] is not None else Origin.DEFAULT,
                            strength_from=Origin.MANIFEST))
    sky = Sky(radiance_sh=sky_sh, ground=pp.ground, up=up,
              strength_from=Origin.PROBE if probe is not None else Origin.FIT)
    return LightModel(suns=tuple(suns), lamps=tuple(lamps), sky=sky, shadows=ShadowKind.CAST, source="manifest",
                      up_from=up_from, albedo_offset=pp.albedo_offset, probe=gloss_probe, walls=fp.walls,
                      fit=summary)


def _with_facing(lamp: Lamp, facing) -> Lamp:
    import dataclasses

    return lamp if facing is None else dataclasses.replace(lamp, facing=facing)


def _default_sun_radius() -> float:
    from zcomp_cli.pipeline.lightspec import SUN_RADIUS_DEG

    return SUN_RADIUS_DEG


def _default_lamp_radius() -> float:
    from zcomp_cli.pipeline.lightspec import LAMP_RADIUS_M

    return LAMP_RADIUS_M


def _lamp_column(fp, q, radius_m, facing, steps, cone_samples, seed) -> np.ndarray:
    col = at.lamp_columns(fp, q[None], steps=steps, radius_m=radius_m, cone_samples=cone_samples, seed=seed)[:, 0]
    if facing is not None:
        v = q[None] - fp.points
        d = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        col = col * 4.0 * np.maximum(-(d @ facing), 0.0)
    return col


def _fit_radius(pp, light: FitLight, base_cols: list, settings: PhysicalSettings, seed: int) -> None:
    """Choose a sun's angular radius among RADII_DEG by the held-out pixels (in place);
    the default radius where they cannot tell (a likelihood under one held-out block's
    worth of evidence)."""
    fp = pp.fp
    steps = settings.estimate_march_steps
    if light.radius >= 0:
        light.column = at.sun_column(fp, light.param, light.radius, steps=steps,
                                     cone_samples=settings.cone_samples, seed=seed)
        return
    radii = (_default_sun_radius(),) + tuple(RADII_DEG)
    cols = [at.sun_column(fp, light.param, r, steps=steps, cone_samples=settings.cone_samples, seed=seed)
            for r in radii]
    y = pp.lum
    B = np.stack(base_cols, 1) if base_cols else np.zeros((len(y), 0))
    if B.shape[1] == 0:
        B = np.ones((len(y), 1))
    scale = max(float(np.median(np.abs(y[fp.train]))), 1e-12)
    sig = base_sigma(B[fp.train], y[fp.train], scale=scale)
    lh, _ = score_candidates(B, np.stack(cols, 1), y, fp.train, sigma=sig)
    w = tempered_likelihood(lh, (sig / scale) ** 2, held_out_blocks(fp))
    i = int(np.argmin(lh))
    if w[0] > np.exp(-1.0):  # the default is within one unit of log-likelihood of the best
        i = 0
    light.radius, light.column = radii[i], cols[i]
    light.radius_from = Origin.DEFAULT if i == 0 else Origin.FIT


def _unfitted(pp, specs, fixed_parts, autos, ratio_specs, up, up_from, note) -> LightModel:
    """The manifest's lights where nothing can be fitted: directions kept, strengths from
    the prior split of a mid-grey level."""
    from zcomp_cli.renderers.physical.estimate import prior_model

    base = prior_model(pp, up, up_from, note)
    level = float(base.sky.shading(up[None])[0].mean())
    suns, lamps = [], []
    for s in specs:
        if s["type"] == "sun":
            d = light_direction(s, pp.frame)
            suns.append(Sun(direction=d, radius_deg=s["angular_radius_deg"] or _default_sun_radius(),
                            irradiance=np.full(3, level), direction_from=Origin.MANIFEST,
                            strength_from=Origin.PRIOR))
        elif s["type"] == "lamp":
            q = np.asarray(s["position"], np.float64)
            lamps.append(Lamp(position=q, radius_m=s["radius_m"] or _default_lamp_radius(),
                              intensity=np.full(3, level * float(q @ q)), position_from=Origin.MANIFEST,
                              strength_from=Origin.PRIOR))
    import dataclasses

    return dataclasses.replace(base, suns=tuple(suns), lamps=tuple(lamps), source="manifest",
                               shadows=ShadowKind.CAST)


__all__ = ["fit_known", "light_direction", "SUN_SHADING_PER_IRRADIANCE", "LAMP_SHADING_PER_WATT"]
