"""The light tree fitted to the photograph: one solver for an estimated and a given light
(DESIGN.md section 8; ``zcomp_cli.lightparams``).

``fit_light(params, ...)`` takes a ``LightParams`` whose frozen parameters it keeps and
whose free ones it fits, in the steps of ``estimate`` (its module docstring):

1. ``estimate.prepare``: fit pixels, the depth mesh and its ray tracer, the bounce, the
   albedo's offset;
2. the lights with **physical strengths** -- a probe (its compact sources and its sky), suns
   with an ``irradiance`` (W/m^2), lamps with a ``power`` (W) -- add up to one coloured
   atom: they hold relative to each other and its one weight is the photograph's
   exposure;
3. a light whose **direction is free** is found by ``estimate.search`` (the posterior over
   directions from the cast shadows and the shading; it may turn out a lamp); one whose
   direction is given has a posterior concentrated there (no spread);
4. a free **angular radius** is chosen among ``search.radii_deg`` and the Sun's by the same
   likelihoods, the Sun's where they cannot tell (``estimate.choose_size``: one rule for
   every sun); a searched light's
   radius then grows to cover its posterior's spread (the hedge); a lamp's free radius
   is a bulb's (``LAMP_RADIUS_M``: a lamp's size is not fitted);
5. a free **strength**: the key light (the first one free) and the sky share the support's
   level by the split the shadows show (``estimate.split_from_shadows``: the
   shadowed/lit ratio across the edges of the shadow it casts, as much as that shadow
   falls on cast shadows tied to their casters, shrunk toward the prior), in one atom
   whose weight is fitted; other free lights are atoms of their own; without a
   probe the sky's shape is fitted (the sky lobes), with one it is the probe's. A sun's
   older ``share`` (direct over sky) ties it to a uniform sky in one atom;
6. one robust NNLS (``solver.fit``) of all atoms, then the ``LightModel``: every light
   with its parameters and where each came from.

Units (Blender's, so a scene lit in Blender can be given as it is; checked against
Cycles in the tests): a probe's radiance is shading as it is (a uniform sky of radiance
L shades a surface with L); a sun of irradiance E (W/m^2) gives ``E / pi`` on a surface
facing it; a point lamp of power P (W) gives ``P / (4 pi^2 r^2)`` at distance r.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.lightparams import LAMP_RADIUS_M, SUN_RADIUS_DEG, LightParams, Origin
from zcomp_cli.renderers.physical import atoms as at
from zcomp_cli.renderers.physical import estimate as est
from zcomp_cli.renderers.physical import sh
from zcomp_cli.renderers.physical.lightmodel import FitSummary, Lamp, LightModel, ShadowKind, Sky, Sun
from zcomp_cli.renderers.physical.posterior import DirectionPosterior
from zcomp_cli.renderers.physical.settings import DEFAULTS, PhysicalSettings
from zcomp_cli.renderers.physical.solver import Atom, fit

# Physical: Blender's units in zcomp's shading (module docstring).
SUN_SHADING_PER_IRRADIANCE = 1.0 / math.pi
LAMP_SHADING_PER_WATT = 1.0 / (4.0 * math.pi ** 2)


@dataclass
class _Light:
    """A sun or lamp while the solver runs: its ``FitLight`` (kind, direction or position,
    radius, column), its colour, where each parameter came from, and for a light with a
    physical strength that strength in shading units (else None: fitted)."""

    fl: est.FitLight
    color: np.ndarray
    direction_from: Origin
    strength: np.ndarray | None = None
    strength_from: Origin = Origin.FIT


def _support_unit(column: np.ndarray, sup: np.ndarray) -> float | None:
    """A light's shading on the support that its share of the level is measured in:
    the median over the support's fit pixels, else (a light that reaches less than half
    of it) the mean over those it reaches; None where it reaches none (nothing to
    split)."""
    c = np.asarray(column, np.float64)[sup]
    m = float(np.median(c)) if len(c) else 0.0
    if m > 1e-9:
        return m
    lit = c[c > 1e-9]
    return float(lit.mean()) if len(lit) else None


def _sun_columns(fp, d, r, settings, seed):
    return at.sun_column(fp, d, r, steps=settings.estimate_march_steps, cone_samples=settings.cone_samples, seed=seed)


def _lamp_column(fp, q, radius_m, facing, settings, seed) -> np.ndarray:
    col = at.lamp_columns(fp, q[None], steps=settings.estimate_march_steps, radius_m=radius_m,
                          cone_samples=settings.cone_samples, seed=seed)[:, 0]
    if facing is not None:
        v = q[None] - fp.points
        d = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        col = col * 4.0 * np.maximum(-(d @ facing), 0.0)
    return col


def fit_light(params: LightParams | None, depth, normals, shading, known, albedo, camera: Camera, *, up,
              up_from: Origin = Origin.SUPPORT, settings: PhysicalSettings = DEFAULTS,
              seed: int = 0, diagnostics: dict | None = None) -> tuple[LightModel, DirectionPosterior | None]:
    """The light of ``params`` (None: ``LightParams.estimate()``) fitted to the
    photograph's known shading (module docstring).

    Args:
        depth: (H, W) z-depth, 0 invalid. normals: (H, W, 3) camera frame.
        shading: (H, W, 3) linear image / albedo, used where ``known`` (H, W) bool.
        albedo: (H, W, 3) linear albedo. camera: the view.
        up: (3,) world up, camera frame; ``up_from`` where it came from.
        diagnostics: a dict to fill with what the fit read, for the debug outputs:
            ``mesh`` (the shadow grid's ``depthmesh.DepthMesh``) and, where a direction
            is searched, ``evidence`` (``shadow_evidence.ShadowEvidence``).
    Returns:
        (LightModel, the searched light's posterior over directions or None). Never
        raises on degenerate evidence: too few pixels give the prior's strengths.
    """
    params = LightParams.estimate() if params is None else params
    up = np.asarray(up, np.float64)
    pp = est.prepare(depth, normals, shading, known, albedo, camera, up, settings)
    if diagnostics is not None and pp.grid is not None:
        diagnostics["mesh"] = pp.grid.mesh
    fp = pp.fp
    source = "manifest" if params.given else "estimated"
    few = settings.search.few_pixels
    if len(fp) < few or fp.train.sum() < few // 2:
        return _unfitted(pp, params, up, up_from, source,
                         f"too few known pixels with geometry ({len(fp)} < {few})"), None
    # step 2: the lights of physical strengths, one atom
    fixed = np.zeros((len(fp), 3))
    n_fixed = 0
    lights: list[_Light] = []
    probe = None
    if params.probe is not None:
        from zcomp_cli.renderers.physical.probe import load_given_probe

        pr = params.probe
        probe = load_given_probe(pr, pp.frame, cfg=settings.probe)
        k = float(pr.strength)
        fixed += k * at.sky_atom_values(fp, probe.sky_radiance_sh, pp.sky_vis)
        n_fixed += 1
        for src in probe.sources:
            col = _sun_columns(fp, src.direction, src.radius_deg, settings, seed)
            e = k * src.power * SUN_SHADING_PER_IRRADIANCE
            fixed += col[:, None] * e[None]
            lights.append(_Light(est.FitLight("sun", src.direction, src.radius_deg, col, Origin.PROBE),
                                 np.ones(3), Origin.PROBE, e, Origin.PROBE))
    search = sc = None
    shares = []  # the older form's suns: (light, direct over sky)
    for sp in params.suns:
        color = np.asarray(sp.color, np.float64)
        if not sp.direction_given:
            if search is not None:
                raise ValueError("fit_light: at most one light's direction can be searched")
            search, sc = est.search(pp, settings, seed)
            if diagnostics is not None:
                diagnostics["evidence"] = search.evidence
            fl = search.light
            lights.append(_Light(fl, color, Origin.SHADOWS))
            continue
        d = sp.direction_in(up)
        if float(d @ up) <= 0.0:
            from zcomp_cli.errors import InputError
            from zcomp_cli.worldframe import angles_from_direction

            raise InputError(f"the manifest's sun (direction {np.round(d, 4).tolist()} in the camera frame) is "
                             f"{-angles_from_direction(d, up)[1]:.1f} deg below the horizon (world up {up_from}): "
                             "it lights nothing the camera sees from above; give a direction above the ground")
        r = float(settings.shadow_softness) if settings.shadow_softness is not None else sp.radius_deg.value
        r_from = Origin.MANIFEST if (settings.shadow_softness is not None or sp.radius_deg.frozen) else Origin.FIT
        fl = est.FitLight("sun", d, None if r is None else float(r), np.zeros(len(fp)), r_from)
        if sp.irradiance.frozen:
            if fl.radius is None:
                fl.radius, fl.radius_from = SUN_RADIUS_DEG, Origin.DEFAULT
            fl.column = _sun_columns(fp, d, fl.radius, settings, seed)
            e = float(sp.irradiance.value) * SUN_SHADING_PER_IRRADIANCE * color
            fixed += fl.column[:, None] * e[None]
            n_fixed += 1
            lights.append(_Light(fl, color, Origin.MANIFEST, e, Origin.MANIFEST))
        elif sp.share is not None:
            if fl.radius is None:
                fl.radius, fl.radius_from = SUN_RADIUS_DEG, Origin.DEFAULT
            fl.column = _sun_columns(fp, d, fl.radius, settings, seed)
            lt = _Light(fl, color, Origin.MANIFEST)
            lights.append(lt)
            shares.append((lt, float(sp.share)))
        else:
            if fl.radius is not None:  # a given size: its column now (a free one is chosen below)
                fl.column = _sun_columns(fp, d, fl.radius, settings, seed)
            lights.append(_Light(fl, color, Origin.MANIFEST))
    for lp in params.lamps:
        q = np.asarray(lp.position.value, np.float64)
        rm = float(lp.radius_m.value) if lp.radius_m.frozen else LAMP_RADIUS_M
        facing = None if lp.facing is None else np.asarray(lp.facing, np.float64)
        col = _lamp_column(fp, q, rm, facing, settings, seed)
        if fp.support.sum() >= 3:
            floor = float(np.median(fp.points[fp.support] @ up))
            if float(q @ up) - floor < -rm:
                from zcomp_cli.errors import InputError

                raise InputError(f"the manifest's lamp at {np.round(q, 3).tolist()} (camera frame, metres) is "
                                 f"{floor - float(q @ up):.2f} m below the floor the scene stands on (world up "
                                 f"{up_from}): it lights none of the surfaces the camera sees")
        if not np.any(col > 0):
            from zcomp_cli.errors import InputError

            raise InputError(f"the manifest's lamp at {np.round(q, 3).tolist()} (camera frame, metres) lights none "
                             "of the surfaces the camera sees (under the floor, behind a wall, or facing away): "
                             "its strength cannot be fitted, nor can it light the object as the photograph shows")
        fl = est.FitLight("lamp", q, rm, col, Origin.MANIFEST if lp.radius_m.frozen else Origin.DEFAULT, facing)
        color = np.asarray(lp.color, np.float64)
        if lp.power.frozen:
            e = float(lp.power.value) * LAMP_SHADING_PER_WATT * color
            fixed += col[:, None] * e[None]
            n_fixed += 1
            lights.append(_Light(fl, color, Origin.MANIFEST, e, Origin.MANIFEST))
        else:
            lights.append(_Light(fl, color, Origin.MANIFEST))
    free = [lt for lt in lights if lt.strength is None and not any(lt is s for s, _ in shares)]
    # steps 3-4: the free lights' sizes (one rule), the searched one's hedge
    if free and sc is None:
        _, sc = est.search_scorer(pp, settings)
    spread = 0.0
    for lt in free:
        fl = lt.fl
        if fl.kind == "sun" and fl.radius is None:
            est.choose_size(pp, sc, fl, settings, seed)
        elif fl.kind == "lamp" and fl.radius is None:
            fl.radius, fl.radius_from = LAMP_RADIUS_M, Origin.DEFAULT
            fl.column = _lamp_column(fp, fl.param, fl.radius, fl.facing, settings, seed)
    hedged = False
    if search is not None:
        spread = search.posterior.rms_angle_deg()
        # (a size the renderer's settings force is kept: no hedge)
        if settings.shadow_softness is None:
            hedged = est.hedge(pp, search.light, spread, settings, seed)
    # step 5: the key light's split with the sky, from the shadows
    sup = fp.support if fp.support.sum() >= 3 else np.ones(len(fp), bool)
    lobes = est.sky_atoms(pp) if probe is None else []
    atoms: list[Atom] = []
    key = free[0] if free else None
    share, n_eff = settings.search.prior_sky_share, 0.0
    sky_unit = light_unit = 1.0
    if key is not None and lobes:
        # (a searched light's split is read across its most probable shadow's edges)
        at_light = search.map_light if (search is not None and key.fl is search.light) else key.fl
        share, n_eff = est.split_from_shadows(sc, at_light)
    light_unit = _support_unit(key.fl.column, sup) if key is not None else None
    if key is not None and lobes and light_unit is not None:
        sky_unit = max(float(np.median(lobes[0].values[sup])), 1e-9)
        atoms.append(Atom("key", share * lobes[0].values / sky_unit + (1.0 - share) * key.fl.column / light_unit))
        atoms += lobes[1:]
    else:
        # (no sky lobes, or a key light that reaches none of the support: a sun behind a
        # wall cannot share the support's level; its own atom, the fit's weight)
        atoms += lobes
        if key is not None:
            atoms.append(Atom("light0", key.fl.column))
    for i, lt in enumerate(free[1:], start=1):
        atoms.append(Atom(f"light{i}", lt.fl.column))
    if shares:
        lobe = dict(at.sky_lobes(pp.frame))["sky"]
        unit_up = max(float(sh.evaluate(sh.shading_coeffs(lobe[:, None]), up[None])[0, 0]), 1e-9)
        comp = at.sky_atom_values(fp, lobe, pp.sky_vis) / unit_up
        for lt, k in shares:
            comp = comp + k * lt.fl.column
        atoms = [a for a in atoms if not a.name.startswith("sky") and a.name != "key"] + [Atom("ratio", comp)]
    if n_fixed:
        atoms.append(Atom("fixed", fixed))
    level = np.median(pp.shading[sup], axis=0)
    prior = est.prior_weights(atoms, pp, [a.name for a in atoms if a.name.startswith("light")],
                              settings.search.prior_sky_share)
    if "key" in [a.name for a in atoms]:
        prior["key"] = level
    direct = [a.name for a in atoms if a.name in ("key", "fixed", "ratio") or a.name.startswith("light")]
    res = fit(atoms, pp.shading, train=fp.train, prior=prior, ridge=settings.solver.prior_ridge, direct=direct,
              cfg=settings.solver)
    # step 6: the model
    w = res.weights
    exposure = float(np.mean(w["fixed"])) if n_fixed else float("nan")
    sky_w = {n_: v for n_, v in w.items() if n_.startswith("sky")}
    if "key" in w:
        sky_w["sky"] = share * np.asarray(w["key"]) / sky_unit
    extra_sh = np.zeros((sh.N_COEFFS, 3))
    if probe is not None:
        extra_sh += exposure * float(params.probe.strength) * probe.sky_radiance_sh
    if "ratio" in w:
        lobe = dict(at.sky_lobes(pp.frame))["sky"]
        unit_up = max(float(sh.evaluate(sh.shading_coeffs(lobe[:, None]), up[None])[0, 0]), 1e-9)
        extra_sh += lobe[:, None] * (np.asarray(w["ratio"]) / unit_up)[None]
    suns, lamps = [], []
    for lt in lights:
        fl = lt.fl
        if lt.strength is not None:
            e, s_from = exposure * lt.strength, lt.strength_from
        elif any(lt is s for s, _ in shares):
            e, s_from = np.asarray(w["ratio"]) * next(k for s, k in shares if s is lt), Origin.MANIFEST
        elif lt is key and "key" in w:
            e, s_from = (1.0 - share) * np.asarray(w["key"]) / light_unit, (Origin.SHADOWS if n_eff > 0 else Origin.PRIOR)
        else:
            # (by identity: a light's == compares its arrays)
            e, s_from = np.asarray(w[f"light{next(i for i, f in enumerate(free) if f is lt)}"]), Origin.FIT
        # (a searched direction with no shadow read came from the shading's fit and the prior)
        d_from = Origin.FIT if lt.direction_from is Origin.SHADOWS and not n_eff > 0 else lt.direction_from
        if fl.kind == "sun":
            suns.append(Sun(direction=fl.param, radius_deg=fl.radius, irradiance=e, direction_from=d_from,
                            radius_from=fl.radius_from, strength_from=s_from))
        else:
            lamps.append(Lamp(position=fl.param, radius_m=fl.radius, intensity=e, facing=fl.facing,
                              position_from=d_from, radius_from=fl.radius_from, strength_from=s_from))
    note = ""
    if hedged:
        fl = search.light
        note = (f"the photograph fixes the light's direction to within {spread:.0f} deg (RMS): its shadow is drawn "
                f"as soft as that ({fl.radius:.3g} {'deg' if fl.kind == 'sun' else 'm'} radius)")
    # (the hedge reached the widest light: a lamp's as well as a sun's, its radius in
    # metres covering that angle from the anchor)
    unfixed = bool(hedged and min(settings.search.cone_per_rms * spread, settings.search.max_radius_deg)
                   >= settings.search.max_radius_deg - 1e-9)
    summary = FitSummary(shadow_blocks=float(n_eff), uncertainty_deg=float(spread) if search is not None else float("nan"),
                         residual=float(res.loss_train), pixels=len(fp), exposure=exposure, note=note,
                         unfixed=unfixed)
    sky = Sky(radiance_sh=est.sky_from_weights(pp, sky_w, extra_sh), ground=pp.ground, up=up,
              strength_from=Origin.PROBE if probe is not None else Origin.FIT)
    model = LightModel(suns=tuple(suns), lamps=tuple(lamps), sky=sky, shadows=ShadowKind.CAST, source=source,
                       up_from=up_from, albedo_offset=pp.albedo_offset,
                       probe=None if probe is None else probe.gloss.scaled(exposure * float(params.probe.strength)),
                       walls=fp.walls, fit=summary, anchor=pp.anchor)
    return model, (search.posterior if search is not None else None)


def _unfitted(pp, params: LightParams, up, up_from, source: str, note: str) -> LightModel:
    """The tree's lights where nothing can be fitted: given directions kept, strengths
    from the prior split of the support's level (or mid-grey)."""
    import dataclasses

    base = est.prior_model(pp, up, up_from, note)
    level = float(base.sky.shading(up[None])[0].mean())
    suns, lamps = [], []
    for s in params.suns:
        if s.direction_given:
            suns.append(Sun(direction=s.direction_in(up), radius_deg=s.radius_deg.value or SUN_RADIUS_DEG,
                            irradiance=np.full(3, level), direction_from=Origin.MANIFEST, strength_from=Origin.PRIOR))
    for lp in params.lamps:
        q = np.asarray(lp.position.value, np.float64)
        lamps.append(Lamp(position=q, radius_m=lp.radius_m.value or LAMP_RADIUS_M,
                          intensity=np.full(3, level * float(q @ q)), position_from=Origin.MANIFEST,
                          strength_from=Origin.PRIOR))
    return dataclasses.replace(base, suns=tuple(suns), lamps=tuple(lamps), source=source,
                               shadows=ShadowKind.CAST if (suns or lamps) else ShadowKind.CONTACT)


__all__ = ["fit_light", "SUN_SHADING_PER_IRRADIANCE", "LAMP_SHADING_PER_WATT"]
