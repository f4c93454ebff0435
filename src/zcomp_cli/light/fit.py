"""The light tree fitted to the photograph: one solver for an estimated and a given light
(DESIGN.md section 8; ``scene.lightparams``).

``fit_light(params, ...)`` takes a ``LightParams`` whose frozen values it keeps and whose
free ones it fits, and gives back the **same tree** with every free value filled and
its origin set, the ``LightModel`` derived from it, the searched light's posterior and
the evidence read. Every node of the tree is a **term** (``ProbeTerm``, ``SunTerm``,
``LampTerm``, ``SkyTerm``) that contributes its columns through one protocol:

1. ``prepare.prepare``: the fit pixels, the depth mesh and its ray tracer, the bounce,
   the scene's specular layer, the sky lobes' columns;
2. ``Term.resolve``: each term's geometry -- a given direction or position as it is, a
   free direction searched (``search.search``: the posterior over directions from the
   cast shadows and the shading; the light found may be a lamp), a free angular radius
   chosen (``search.choose_size``: from its shadow's soft edge, never from the
   direction's doubt), a searched light drawn as its posterior's modes (each a sun or a
   lamp of the mass it holds, all at the one size chosen) and the rest of its mass as
   sky;
3. ``Term.columns``: what each term adds to the known shading at unit strength
   (``Column``), with how its strength is had -- **absolute** (a probe, an
   ``irradiance``, a ``power``, a frozen sky: physical units that hold relative to each
   other, their one weight the photograph's exposure), or **free** (fitted);
4. ``_atoms``: the columns into the solver's atoms. Columns whose strengths are tied
   share one atom: the absolute ones (the exposure); the sky's uniform lobe and the
   key light (the first free one), by the split the shadows show
   (``search.split_from_shadows``); the uniform sky and a sun given by the older
   ``share`` (direct over sky). The others are atoms of their own;
5. one robust NNLS (``solver.fit``) of all atoms (none where nothing is free; the
   priors where too few pixels fit anything);
6. ``Term.fill``: each term takes its columns' strengths back: the filled tree, and its
   lights in the model's units.

Units (Blender's, so a scene lit in Blender can be given as it is; checked against
Cycles in the tests): a probe's radiance is shading as it is (a uniform sky of radiance
L shades a surface with L); a sun of irradiance E (W/m^2) gives ``E / pi`` on a surface
facing it; a point lamp of power P (W) gives ``P / (4 pi^2 r^2)`` at distance r. A
filled free strength is written in the same units (the photograph's exposure 1 where no
light was given in them).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.errors import InputError
from zcomp_cli.light import atoms as at
from zcomp_cli.light import search as sr
from zcomp_cli.light.config import LightConfig
from zcomp_cli.light.ledger import timed
from zcomp_cli.light.posterior import DirectionPosterior
from zcomp_cli.light.prepare import Prepared, prepare, reads_shadows
from zcomp_cli.light.solver import Atom, fit
from zcomp_cli.scene import sh
from zcomp_cli.scene.lightmodel import FitSummary, Lamp, LightModel, ProbeRef, ShadowKind, Sky, Sun
from zcomp_cli.scene.lightparams import (LAMP_RADIUS_M, SUN_RADIUS_DEG, LampParams, LightParams, Origin, Param,
                                         SkyParams)

# Physical: Blender's units in zcomp's shading (module docstring).
SUN_SHADING_PER_IRRADIANCE = 1.0 / math.pi
LAMP_SHADING_PER_WATT = 1.0 / (4.0 * math.pi ** 2)
# Origins of a direction or position that the photograph did not give: a light whose
# direction has one of them is an estimate (its shadow fades at the shading mask's edge
# instead of being grown along it: ``LightModel.source``).
ESTIMATED = (Origin.SHADOWS, Origin.FIT, Origin.PRIOR, Origin.DEFAULT)


@dataclass
class Column:
    """What a term adds to the known shading at unit strength: ``values`` (N,) grey or
    (N, 3) coloured; ``absolute`` (3,) its strength in shading units per unit exposure
    where the tree gives it in physical units (None: fitted); ``direct``: an unseen
    occluder can hide it (a sun's, a lamp's); ``kind`` ``light``, ``lobe`` (a sky lobe,
    ``lobe`` its index) or ``sky`` (a whole coloured sky); ``strength`` (3,) set by the
    solve."""

    values: np.ndarray
    absolute: np.ndarray | None = None
    direct: bool = False
    kind: str = "light"
    lobe: int = -1
    strength: np.ndarray | None = None


@dataclass
class Context:
    """What every term reads while the fit runs: the prepared scene, the config, the seed,
    world up and where it came from; the scorer of candidate lights (made on first ask),
    the searched light's search, and the fit's diagnostics."""

    pp: Prepared
    cfg: LightConfig
    seed: int
    up: np.ndarray
    up_from: Origin
    fitting: bool = True
    search: sr.Search | None = None
    _scorer: object = None
    diagnostics: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)

    def scorer(self):
        """The shadow evidence's scorer (``search.search_scorer``), made once."""
        if self._scorer is None:
            ev, self._scorer = sr.search_scorer(self.pp, self.cfg)
            self.diagnostics.setdefault("evidence", ev)
        return self._scorer

    @property
    def support(self) -> np.ndarray:
        fp = self.pp.fp
        return fp.support if fp.support.sum() >= 3 else np.ones(len(fp), bool)


class Term:
    """One node of the tree while the fit runs (module docstring): ``resolve`` its
    geometry, ``columns`` its contribution, ``fill`` the node and its model lights back
    from its columns' strengths."""

    node: object
    cols: list

    def resolve(self, ctx: Context) -> None:
        """Step 2 (nothing to resolve by default)."""

    def columns(self, ctx: Context) -> list[Column]:
        raise NotImplementedError

    def fill(self, ctx: Context, exposure: float):
        """Step 6: (the filled node, its model suns, its model lamps, its sky radiance SH
        (9, 3) camera frame or None)."""
        raise NotImplementedError


def _rgb(v, color=(1.0, 1.0, 1.0)) -> np.ndarray:
    return np.broadcast_to(np.asarray(v, np.float64), (3,)) * np.asarray(color, np.float64)


def _times(value, k: float) -> np.ndarray:
    """A given strength (one number, or RGB once fitted) in shading units: ``value * k``."""
    return (float(value) * k if np.ndim(value) == 0 else np.asarray(value, np.float64) * k) * np.ones(3)


def _physical(e_rgb: np.ndarray, per_unit: float, exposure: float) -> tuple:
    """A strength in shading units as the tree writes it: physical units at the
    photograph's ``exposure`` (1 where no light fixes it), RGB."""
    k = exposure if (math.isfinite(exposure) and exposure > 0) else 1.0
    return tuple(float(x) for x in np.asarray(e_rgb, np.float64) / (per_unit * k))


class ProbeTerm(Term):
    """A given probe: its sky and its compact sources (``scene.probe``), absolute."""

    def __init__(self, node):
        self.node = node

    def resolve(self, ctx):
        from zcomp_cli.scene.probe import load_given_probe

        self.lights = load_given_probe(self.node, ctx.pp.frame, cfg=ctx.cfg.probe)

    def columns(self, ctx):
        pp, k = ctx.pp, float(self.node.strength)
        self.cols = [Column(at.sky_atom_values(pp.fp, self.lights.sky_radiance_sh, pp.sky_vis,
                                               self.lights.sky_radiance_at), np.full(3, k), kind="sky")]
        self.sources = []
        for src in self.lights.sources:
            col = sr.sun_column(pp.fp, src.direction, src.radius_deg, ctx.cfg, ctx.seed)
            self.cols.append(Column(col, k * src.power * SUN_SHADING_PER_IRRADIANCE, direct=True))
            self.sources.append(src)
        return self.cols

    def fill(self, ctx, exposure):
        suns = [Sun(direction=src.direction, radius_deg=src.radius_deg, irradiance=c.strength,
                    direction_from=Origin.PROBE, radius_from=Origin.PROBE, strength_from=Origin.PROBE)
                for src, c in zip(self.sources, self.cols[1:])]
        sky = exposure * float(self.node.strength) * self.lights.sky_radiance_sh
        return self.node, suns, [], sky

    def ref(self, ctx, exposure) -> ProbeRef:
        from zcomp_cli.knobs import as_dict

        return ProbeRef(params=self.node, scale=exposure * float(self.node.strength), frame=ctx.pp.frame,
                        cfg=as_dict(ctx.cfg.probe))


class _DirectTerm(Term):
    """A sun or a lamp (``search.FitLight`` once resolved)."""

    light: sr.FitLight
    color: np.ndarray
    origin: Origin  # where its direction or position came from
    strength_origin: Origin = Origin.FIT
    share: float | None = None

    def absolute(self) -> np.ndarray | None:
        return None

    def columns(self, ctx):
        self.cols = [Column(self.light.column, self.absolute(), direct=True)]
        return self.cols

    def model_light(self, e: np.ndarray, s_from: Origin, fl: sr.FitLight | None = None):
        fl = self.light if fl is None else fl
        if fl.kind == "sun":
            return [Sun(direction=fl.param, radius_deg=fl.radius, irradiance=e, direction_from=self.origin,
                        radius_from=fl.radius_from, strength_from=s_from)], []
        return [], [Lamp(position=fl.param, radius_m=fl.radius, intensity=e, facing=fl.facing,
                         position_from=self.origin, radius_from=fl.radius_from, strength_from=s_from)]


class SunTerm(_DirectTerm):
    """A sun of the tree: its direction given (or its angles, resolved with world up) or
    searched (the light found may be a lamp), its radius given, forced by the config's
    ``shadow_softness``, chosen or grown; its irradiance given (absolute), tied to the
    sky by the older ``share``, or fitted."""

    def __init__(self, node):
        self.node = node
        self.color = np.asarray(node.color, np.float64)
        self.share = node.share if not node.irradiance.frozen else None
        self.searched = not node.direction_given
        self.modes: list = []  # a searched light's drawn modes: (FitLight, share) each
        self.rest_sh = None  # and the rest of its posterior as sky (SH per unit strength)

    def resolve(self, ctx):
        cfg, fp = ctx.cfg, ctx.pp.fp
        if self.searched:
            if ctx.search is not None:
                raise ValueError("fit_light: at most one light's direction can be searched")
            ctx.search, sc = sr.search(ctx.pp, cfg, ctx.seed)
            ctx._scorer = sc
            ctx.diagnostics["evidence"] = ctx.search.evidence
            ctx.diagnostics["search_anchor"] = ctx.search.anchor  # where its lamps' directions are from
            self.light, self.origin = ctx.search.light, Origin.SHADOWS
            self.modes = list(ctx.search.modes)
            return
        d = self.node.direction_in(ctx.up)
        if float(d @ ctx.up) <= 0.0:
            from zcomp_cli.worldframe import angles_from_direction

            raise InputError(f"the manifest's sun (direction {np.round(d, 4).tolist()} in the camera frame) is "
                             f"{-angles_from_direction(d, ctx.up)[1]:.1f} deg below the horizon (world up "
                             f"{ctx.up_from}): it lights nothing the camera sees from above; give a direction above "
                             "the ground")
        self.origin = self.node.direction_origin
        rp = self.node.radius_deg
        if cfg.shadow_softness is not None:
            r, r_from = float(cfg.shadow_softness), Origin.MANIFEST
        elif rp.frozen:
            r, r_from = float(rp.value), rp.origin
        elif not ctx.fitting:
            r, r_from = SUN_RADIUS_DEG, Origin.DEFAULT  # too few pixels to choose its size by
        else:
            r, r_from = None, Origin.FIT
        col = sr.sun_column(fp, d, r, cfg, ctx.seed) if r is not None else np.zeros(len(fp))
        self.light = sr.FitLight("sun", d, r, col, r_from)

    def absolute(self):
        p = self.node.irradiance
        if not p.frozen:
            return None
        self.strength_origin = p.origin
        return _times(p.value, SUN_SHADING_PER_IRRADIANCE) * self.color

    def columns(self, ctx):
        """A searched light's column is its modes' (``search.Search.modes``), each at its
        share, and the rest of the posterior's mass as sky (``rest_sh``): one atom, so
        the drawn light keeps the posterior's proportions and the split the shadows
        show."""
        if not self.modes:
            return super().columns(ctx)
        col = sum(w * fl.column for fl, w in self.modes)
        rest = ctx.search.rest_sh
        if rest is not None and len(ctx.pp.fp):
            col = col + at.sky_atom_values(ctx.pp.fp, rest, ctx.pp.sky_vis)
            self.rest_sh = np.asarray(rest, np.float64)
        self.cols = [Column(np.asarray(col, np.float64), self.absolute(), direct=True)]
        return self.cols

    def fill(self, ctx, exposure):
        e = self.cols[0].strength
        if not self.modes:
            return self._filled_one(self.light, e, exposure)
        nodes, suns, lamps = [], [], []
        for fl, w in self.modes:  # (heaviest first: the key light the report names)
            node, s_, l_, _ = self._filled_one(fl, np.asarray(e, np.float64) * w, exposure)
            nodes.append(node)
            suns += s_
            lamps += l_
        rest = None if self.rest_sh is None else np.outer(self.rest_sh, np.broadcast_to(np.asarray(e, np.float64), 3))
        return nodes, suns, lamps, rest

    def _filled_one(self, fl: sr.FitLight, e: np.ndarray, exposure: float):
        """(its node, model suns, model lamps, None) of one drawn light ``fl`` of strength ``e``."""
        s_from = self.strength_origin
        suns, lamps = self.model_light(e, s_from, fl)
        if fl.kind == "lamp":  # a searched light found a lamp: a lamp in the tree
            node = LampParams(position=Param(value=tuple(fl.param), origin=self.origin),
                              radius_m=Param(value=float(fl.radius), origin=fl.radius_from),
                              power=Param(value=_physical(e, LAMP_SHADING_PER_WATT, exposure), origin=s_from))
            return node, suns, lamps, None
        n = self.node
        node = dataclasses.replace(
            n, direction=n.direction.fill(tuple(fl.param), self.origin),
            radius_deg=n.radius_deg.fill(float(fl.radius), fl.radius_from),
            irradiance=n.irradiance.fill(_physical(e, SUN_SHADING_PER_IRRADIANCE, exposure), s_from),
            color=n.color if n.irradiance.frozen else (1.0, 1.0, 1.0))  # (a fitted strength is RGB)
        return node, suns, lamps, None


class LampTerm(_DirectTerm):
    """A lamp of the tree: its position given, its radius given or a bulb's, its power
    given (absolute) or fitted."""

    def __init__(self, node):
        self.node = node
        self.color = np.asarray(node.color, np.float64)
        self.origin = node.position.origin

    def resolve(self, ctx):
        fp, cfg = ctx.pp.fp, ctx.cfg
        q = np.asarray(self.node.position.value, np.float64)
        rp = self.node.radius_m
        rm, r_from = (float(rp.value), rp.origin) if rp.frozen else (LAMP_RADIUS_M, Origin.DEFAULT)
        facing = None if self.node.facing is None else np.asarray(self.node.facing, np.float64)
        col = sr.lamp_column(fp, q, rm, facing, cfg, ctx.seed)
        if ctx.fitting and fp.support.sum() >= 3:
            floor = float(np.median(fp.points[fp.support] @ ctx.up))
            if float(q @ ctx.up) - floor < -rm:
                raise InputError(f"the manifest's lamp at {np.round(q, 3).tolist()} (camera frame, metres) is "
                                 f"{floor - float(q @ ctx.up):.2f} m below the floor the scene stands on (world up "
                                 f"{ctx.up_from}): it lights none of the surfaces the camera sees")
        if ctx.fitting and not np.any(col > 0):
            raise InputError(f"the manifest's lamp at {np.round(q, 3).tolist()} (camera frame, metres) lights none "
                             "of the surfaces the camera sees (under the floor, behind a wall, or facing away): "
                             "its strength cannot be fitted, nor can it light the object as the photograph shows")
        self.light = sr.FitLight("lamp", q, rm, col, r_from, facing)

    def absolute(self):
        p = self.node.power
        if not p.frozen:
            return None
        self.strength_origin = p.origin
        return _times(p.value, LAMP_SHADING_PER_WATT) * self.color

    def fill(self, ctx, exposure):
        e = self.cols[0].strength
        suns, lamps = self.model_light(e, self.strength_origin)
        fl, n = self.light, self.node
        node = dataclasses.replace(
            n, radius_m=n.radius_m.fill(float(fl.radius), fl.radius_from),
            power=n.power.fill(_physical(e, LAMP_SHADING_PER_WATT, exposure), self.strength_origin),
            color=n.color if n.power.frozen else (1.0, 1.0, 1.0))  # (a fitted strength is RGB)
        return node, suns, lamps, None


class SkyTerm(Term):
    """The sky: given (its radiance frozen, in the ground frame: absolute), fitted (the
    sky lobes, ``atoms.sky_lobes``), or nothing of its own beside a probe (the probe's)."""

    def __init__(self, node: SkyParams, with_probe: bool):
        self.node, self.with_probe = node, with_probe
        self.cols = []

    def resolve(self, ctx):
        from zcomp_cli.worldframe import ground_frame

        self.given = self.node.radiance_sh.frozen
        if self.given:
            self.sh_cam = sh_world_to_camera(np.asarray(self.node.radiance_sh.value, np.float64), ground_frame(ctx.up))
        self.lobes = at.sky_lobes(ctx.pp.frame)

    def columns(self, ctx):
        if self.given:
            self.cols = [Column(at.sky_atom_values(ctx.pp.fp, self.sh_cam, ctx.pp.sky_vis), np.ones(3), kind="sky")]
        elif not self.with_probe:
            self.cols = [Column(ctx.pp.lobe_columns[:, i], None, kind="lobe", lobe=i) for i in range(len(self.lobes))]
        return self.cols

    def fill(self, ctx, exposure):
        if self.given:
            return self.node, [], [], exposure * self.sh_cam
        out = np.zeros((sh.N_COEFFS, 3))
        for c in self.cols:
            if c.strength is not None:
                out += self.lobes[c.lobe][1][:, None] * np.asarray(c.strength)[None]
        return self.node, [], [], out


def sh_world_to_camera(c_world: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """(9, C) SH coefficients of a function given in the ground frame (``frame`` rows:
    its axes in the camera frame) as the same function's in the camera frame. Exact for
    order 2 (a rotation or reflection keeps each band): solved on directions."""
    from zcomp_cli.scene.sampling import fibonacci_sphere

    d = fibonacci_sphere(64)
    Yc = sh.basis(d)
    Yw = sh.basis(d @ np.asarray(frame, np.float64).T)
    return np.linalg.lstsq(Yc, Yw @ np.asarray(c_world, np.float64), rcond=None)[0]


def sh_camera_to_world(c_cam: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """The inverse of ``sh_world_to_camera``."""
    from zcomp_cli.scene.sampling import fibonacci_sphere

    d = fibonacci_sphere(64)
    Yw = sh.basis(d)
    Yc = sh.basis(d @ np.asarray(frame, np.float64))
    return np.linalg.lstsq(Yw, Yc @ np.asarray(c_cam, np.float64), rcond=None)[0]


def _unit(values: np.ndarray, sup: np.ndarray) -> float | None:
    """A column's shading on the support that its share of the level is measured in:
    the median over the support's fit pixels, else (a light that reaches less than half
    of it) the mean over those it reaches; None where it reaches none."""
    c = np.asarray(values, np.float64)[sup]
    m = float(np.median(c)) if len(c) else 0.0
    if m > 1e-9:
        return m
    lit = c[c > 1e-9]
    return float(lit.mean()) if len(lit) else None


@dataclass
class _Tied:
    """An atom: its columns, each with its fixed factor as (multiplier, divisor) (the
    atom's values are the sum of ``mult * values / div``, a column's strength ``mult *
    weight / div``), and the solver's ``Atom`` (its values, prior, direct)."""

    parts: list
    atom: Atom

    @classmethod
    def of(cls, name: str, parts: list, prior=None, direct: bool = False) -> "_Tied":
        """The atom of ``parts``; a direct one keeps its parts that are not direct (the
        sky tied to a sun, the probe's sky under one exposure with a given sun) in an
        unseen shadow (``solver.Atom.kept``)."""
        values, kept = 0, 0
        coloured = any(np.ndim(m) == 1 for _, m, _ in parts) or any(np.ndim(c.values) == 2 for c, _, _ in parts)
        for c, m, d in parts:
            v = np.asarray(c.values, np.float64)
            if np.ndim(m) == 1:  # a coloured factor (an absolute strength): the atom is coloured
                v = (v[:, None] if v.ndim == 1 else v) * np.asarray(m)[None]
                v = v if d == 1.0 else v / d
            else:
                v = v if (m == 1.0 and d == 1.0) else m * v / d
            if coloured and v.ndim == 1:
                v = np.repeat(v[:, None], 3, 1)
            values = values + v
            if not c.direct:
                kept = kept + v
        keep = None
        if direct and not np.isscalar(kept):
            keep = np.broadcast_to(kept, np.shape(values)).astype(np.float64)
        return cls(parts, Atom(name, values, prior=prior, direct=direct, kept=keep))


def _atoms(ctx: Context, terms: list[Term], level: np.ndarray) -> tuple[list[_Tied], float, float, dict]:
    """Step 4 (module docstring): the columns into atoms. Returns (the atoms, the sky's
    share of the support's light and the blocks of shadow behind it, ``{"key": the key
    light's term where it is tied to the sky, "exposure": the exposure atom's index}``,
    None where there is none)."""
    pp, cfg, sup = ctx.pp, ctx.cfg, ctx.support
    cols = [(t, c) for t in terms for c in t.cols]
    absolute = [c for _, c in cols if c.absolute is not None]
    lobes = [c for _, c in cols if c.kind == "lobe"]
    legacy = [t for t in terms if isinstance(t, SunTerm) and t.share is not None]
    free = [(t, c) for t, c in cols if c.kind == "light" and c.absolute is None and t.share is None]
    key = free[0] if free else None
    prior_share = cfg.search.prior_sky_share
    share, n_eff = prior_share, 0.0
    if key is not None and lobes and ctx.fitting:
        t = key[0]
        at_light = ctx.search.map_light if (ctx.search is not None and t.light is ctx.search.light) else t.light
        share, n_eff = sr.split_from_shadows(ctx.scorer(), at_light, t.light.radius)
    light_unit = _unit(key[1].values, sup) if key is not None else None
    tied_key = key is not None and bool(lobes) and light_unit is not None and not legacy
    out: list[_Tied] = []
    if legacy:
        # the older share: the uniform sky and each such sun in one atom (direct over sky);
        # the sky's other lobes are not fitted
        lobe = at.sky_lobes(pp.frame)[0][1]
        unit_up = max(float(sh.evaluate(sh.shading_coeffs(lobe[:, None]), ctx.up[None])[0, 0]), 1e-9)
        ratio = _Tied.of("ratio", [(lobes[0], 1.0, unit_up)] + [(t.cols[0], float(t.share), 1.0) for t in legacy],
                         direct=True)
        lobes = []
    elif tied_key:
        sky_unit = max(float(np.median(lobes[0].values[sup])), 1e-9)
        out.append(_Tied.of("key", [(lobes[0], share, sky_unit), (key[1], 1.0 - share, light_unit)], prior=level,
                            direct=True))
        lobes = lobes[1:]
    for c in lobes:
        prior = None
        if c.lobe == 0:
            unit = max(float(np.median(c.values[sup])), 1e-9) if len(c.values) else 1.0
            prior = prior_share * level / unit
        out.append(_Tied.of(f"sky{c.lobe}", [(c, 1.0, 1.0)], prior=prior))
    rest = free[1:] if tied_key else free
    for _, c in rest:
        unit = float(np.median(c.values[sup])) if len(c.values) else 1.0
        prior = (1.0 - prior_share) * level / unit / len(rest) if unit > 1e-9 else None
        out.append(_Tied.of("light", [(c, 1.0, 1.0)], prior=prior, direct=True))
    if legacy:
        out.append(ratio)
    info = {"key": key[0] if tied_key else None, "exposure": None}
    if absolute:
        ex = _Tied.of("exposure", [(c, c.absolute, 1.0) for c in absolute], direct=True)
        f = np.asarray(ex.atom.values, np.float64)
        ratio_ = np.median(pp.shading[sup] / np.maximum(f[sup], 1e-9), axis=0) if len(f) else np.ones(3)
        info["exposure"] = len(out)
        out.append(dataclasses.replace(ex, atom=dataclasses.replace(ex.atom, prior=float(np.mean(ratio_)))))
    return out, share, n_eff, info


def _solve(ctx: Context, atoms: list[_Tied], exposure: Param, info: dict) -> tuple[list, float]:
    """Step 5: the atoms' (3,) weights, in order, and the solve's residual (nan where
    nothing was solved): the robust NNLS of the free ones; a frozen exposure's atom at
    its value (its light subtracted from what the others explain); the priors where too
    few pixels fit anything."""
    pp, cfg = ctx.pp, ctx.cfg
    fixed = {}
    if info["exposure"] is not None and exposure.frozen:
        fixed[info["exposure"]] = np.full(3, float(exposure.value))
    todo = [i for i in range(len(atoms)) if i not in fixed]
    weights = [None] * len(atoms)
    for i, w in fixed.items():
        weights[i] = w
    if not todo:
        return weights, float("nan")
    if not ctx.fitting:  # the priors (a coloured atom: one weight)
        for i in todo:
            p = atoms[i].atom.prior
            weights[i] = np.zeros(3) if p is None else _rgb(np.mean(p) if np.ndim(atoms[i].atom.values) == 2 else p)
        return weights, float("nan")
    target = pp.shading
    for i, w in fixed.items():
        v = np.asarray(atoms[i].atom.values)
        target = np.maximum(target - (v * w[None] if v.ndim == 2 else v[:, None] * w[None]), 0.0)
    res = fit([atoms[i].atom for i in todo], target, train=pp.fp.train, ridge=cfg.solver.prior_ridge, cfg=cfg.solver)
    for i, w in zip(todo, res.weights):
        weights[i] = np.asarray(w, np.float64)
    return weights, float(res.loss_train)


def _terms(params: LightParams) -> list[Term]:
    """The tree's terms in the fit's order: the probe, the suns, the lamps, the sky."""
    terms: list[Term] = [ProbeTerm(params.probe)] if params.probe is not None else []
    terms += [SunTerm(s) for s in params.suns] + [LampTerm(lp) for lp in params.lamps]
    return terms + [SkyTerm(params.sky, with_probe=params.probe is not None)]


@dataclass(frozen=True)
class LightFit:
    """What ``fit_light`` gives back: the ``model`` (``LightModel``), the filled tree
    (``params``), the searched light's posterior over directions (None: no direction
    was searched), and what the fit read (``diagnostics``: ``mesh``, the shadow grid's
    ``DepthMesh``; ``evidence``, ``evidence.ShadowEvidence``, where shadows were read)."""

    model: LightModel
    params: LightParams
    posterior: DirectionPosterior | None
    diagnostics: dict


def fit_light(params: LightParams | None, depth, normals, shading, known, albedo, camera: Camera, *, up,
              up_from: Origin = Origin.SUPPORT, cfg: LightConfig, seed: int = 0) -> LightFit:
    """The light of ``params`` (None: ``LightParams.estimate()``) fitted to the
    photograph's known shading (module docstring).

    Args:
        depth: (H, W) z-depth, 0 invalid. normals: (H, W, 3) camera frame.
        shading: (H, W, 3) linear image / albedo, used where ``known`` (H, W) bool.
        albedo: (H, W, 3) linear albedo. camera: the view.
        up: (3,) world up, camera frame; ``up_from`` where it came from.
        cfg: the light stage's config. seed: the cone samples' seed.
    Returns:
        ``LightFit``. Never raises on degenerate evidence: too few pixels give the
        priors' strengths (a free direction cannot be found: that light is left out).
    Raises:
        InputError: a given light that lights nothing the camera sees.
    """
    params = LightParams.estimate() if params is None else params
    up = np.asarray(up, np.float64)
    steps: dict = {}  # each step's seconds (the job's ledger: ``light.ledger``)
    with timed(steps, "prepare"):
        pp = prepare(depth, normals, shading, known, albedo, camera, up, cfg, shadows=reads_shadows(params, cfg),
                     steps=steps)
    ctx = Context(pp=pp, cfg=cfg, seed=seed, up=up, up_from=up_from)
    ctx.diagnostics["steps"] = steps
    if pp.grid is not None:
        ctx.diagnostics["mesh"] = pp.grid.mesh
    few = cfg.search.few_pixels
    fp = pp.fp
    if len(fp) < few or fp.train.sum() < few // 2:
        ctx.fitting = False
        ctx.notes.append(f"too few known pixels with geometry ({len(fp)} < {few})")
    terms = _terms(params)
    for t in terms:
        if isinstance(t, SunTerm) and t.searched and not ctx.fitting:
            continue  # nothing to search it with: left out below
        with timed(steps, "probe" if isinstance(t, ProbeTerm) else "search" if getattr(t, "searched", False)
                   else "lights"):
            t.resolve(ctx)
    terms = [t for t in terms if not (isinstance(t, SunTerm) and t.searched and not ctx.fitting)]
    with timed(steps, "sizes"):
        _sizes(ctx, terms)
    for t in terms:
        t.columns(ctx)
    sup = ctx.support
    level = (np.median(pp.shading[sup], axis=0) if len(fp) else np.full(3, 0.5))
    with timed(steps, "solve"):
        atoms, share, n_eff, info = _atoms(ctx, terms, level)
        weights, residual = _solve(ctx, atoms, params.exposure, info)
    exposure = float(np.mean(weights[info["exposure"]])) if info["exposure"] is not None else float("nan")
    for i, (tied, w) in enumerate(zip(atoms, weights)):
        for c, m, d in tied.parts:
            # (the exposure's parts: the one exposure times each absolute strength)
            s_ = exposure * m if i == info["exposure"] else (m * np.asarray(w) / d if (m, d) != (1.0, 1.0)
                                                             else np.asarray(w))
            c.strength = s_ if c.strength is None else c.strength + s_
    return _filled(ctx, params, terms, exposure, share, n_eff, residual, info)


def _sizes(ctx: Context, terms: list[Term]) -> None:
    """Step 2's sizes (``search.choose_size``): a free sun's radius chosen by its shadows'
    likelihoods; the searched light's modes all at the one size chosen at the heaviest
    (a light's size is one, however uncertain its direction), unless the config forces
    one (``shadow_softness``)."""
    for t in terms:
        if isinstance(t, SunTerm) and t.modes:
            s = ctx.search
            fl0 = t.modes[0][0]
            if ctx.cfg.shadow_softness is not None:
                r, origin = float(ctx.cfg.shadow_softness), Origin.MANIFEST
            else:
                r, origin = sr.chosen_radius(ctx.scorer(), fl0, s.anchor, ctx.cfg, ctx.seed)
            t.modes = [(sr.sized(ctx.pp, fl, r, origin, ctx.cfg, ctx.seed, s.anchor), w) for fl, w in t.modes]
            ctx.search = dataclasses.replace(s, light=t.modes[0][0], modes=tuple(t.modes))
            t.light = t.modes[0][0]
        elif isinstance(t, _DirectTerm) and t.light.radius is None:
            _set_light(ctx, t, sr.choose_size(ctx.pp, ctx.scorer(), t.light, ctx.cfg, ctx.seed))


def _set_light(ctx: Context, t: "_DirectTerm", light: sr.FitLight) -> None:
    """The term's light replaced (the search's too, where it is the searched one)."""
    if ctx.search is not None and t.light is ctx.search.light:
        ctx.search = dataclasses.replace(ctx.search, light=light)
    t.light = light


def _filled(ctx: Context, params: LightParams, terms: list[Term], exposure: float, share: float, n_eff: float,
            residual: float, info: dict) -> LightFit:
    """Step 6: the filled tree and its model (module docstring)."""
    pp = ctx.pp
    key = info["key"]
    if key is not None:
        key.strength_origin = Origin.SHADOWS if n_eff > 0 else Origin.PRIOR
    for t in terms:  # (a searched direction with no shadow read came from the shading's fit and the prior)
        if isinstance(t, _DirectTerm) and t.origin is Origin.SHADOWS and not n_eff > 0:
            t.origin = Origin.FIT
    if not ctx.fitting:
        for t in terms:
            if isinstance(t, _DirectTerm) and t.cols[0].absolute is None:
                t.strength_origin = Origin.PRIOR
    for t in terms:
        if isinstance(t, SunTerm) and t.share is not None:
            t.strength_origin = Origin.MANIFEST
    ex = exposure if math.isfinite(exposure) else 1.0
    suns, lamps, node_suns, node_lamps = [], [], [], []
    sky_sh = np.zeros((sh.N_COEFFS, 3))
    probe_ref = None
    for t in terms:
        node, s_, l_, extra = t.fill(ctx, ex)
        if isinstance(t, SkyTerm):
            sky_node = node
        suns += s_
        lamps += l_
        if extra is not None:
            sky_sh += extra
        if isinstance(t, ProbeTerm):
            probe_ref = t.ref(ctx, ex)
        elif isinstance(t, SkyTerm):
            pass
        else:  # (a searched light drawn as its modes fills a node for each)
            for n_ in (node if isinstance(node, list) else [node]):
                (node_lamps if isinstance(n_, LampParams) else node_suns).append(n_)
    sky_from = (Origin.PROBE if params.probe is not None else sky_node.radiance_sh.origin if sky_node.radiance_sh.frozen
                else Origin.FIT if ctx.fitting else Origin.PRIOR)
    ground = (np.asarray(sky_node.ground.value, np.float64) if sky_node.ground.frozen else pp.ground)
    sky = Sky(radiance_sh=sky_sh, ground=ground, up=ctx.up, strength_from=sky_from)
    filled_sky = _filled_sky(sky_node, sky_sh, ground, ctx, sky_from, ex)
    filled = dataclasses.replace(params, suns=tuple(node_suns), lamps=tuple(node_lamps),
                                 sky=filled_sky,
                                 exposure=params.exposure if params.exposure.frozen or not math.isfinite(exposure)
                                 else params.exposure.filled(exposure, Origin.FIT))
    model = _model(ctx, params, suns, lamps, sky, probe_ref, exposure, n_eff, residual, share)
    return LightFit(model=model, params=filled, posterior=ctx.search.posterior if ctx.search is not None else None,
                    diagnostics=ctx.diagnostics)


def _filled_sky(node: SkyParams, sky_sh: np.ndarray, ground: np.ndarray, ctx: Context, origin: Origin,
                exposure: float) -> SkyParams:
    """The sky node with its values: the radiance in the ground frame (module
    docstring of ``lightparams``) in physical units at the photograph's ``exposure``
    (as every filled strength: ``_physical``), the support's radiance."""
    from zcomp_cli.worldframe import ground_frame

    rad = node.radiance_sh if node.radiance_sh.frozen else node.radiance_sh.filled(
        sh_camera_to_world(sky_sh / (exposure if exposure > 0 else 1.0), ground_frame(ctx.up)), origin)
    gr = node.ground.fill(ground, Origin.FIT)
    return SkyParams(radiance_sh=rad, ground=gr)


def _model(ctx: Context, params: LightParams, suns, lamps, sky: Sky, probe_ref, exposure: float, n_eff: float,
           residual: float, share: float = float("nan")) -> LightModel:
    """The ``LightModel`` of the filled terms: its lights, sky, what the fit says of
    itself (the searched light's doubt, and how its modes were drawn)."""
    pp = ctx.pp
    # the doubt the cues state, apart from the chance that they mislead (``misled``)
    spread = ctx.search.posterior.informed.rms_angle_deg() if ctx.search is not None else float("nan")
    misled = ctx.search.posterior.misled if ctx.search is not None else float("nan")
    modes = tuple(ctx.search.modes) if ctx.search is not None else ()
    unfixed = len(modes) > 1
    if unfixed:
        fl = modes[0][0]
        size = f"{fl.radius:.3g} {'deg' if fl.kind == 'sun' else 'm'}"
        ctx.notes.append(
            f"the photograph fixes the light's direction to within {spread:.0f} deg (RMS; unless its cues mislead, "
            f"a {misled:.0%} chance): drawn as the posterior's "
            f"{len(modes)} likeliest lights ({', '.join(f'{w:.0%}' for _, w in modes)} of the light), each at the "
            f"light's size ({size}, {fl.radius_from})"
            + (", the rest of the posterior as sky" if ctx.search.rest_sh is not None else ""))
    note = "; ".join(ctx.notes)
    mode_info = tuple({"kind": fl.kind, "share": round(float(w), 4),
                       "toward": [round(float(v), 6) for v in sr.light_direction(fl, ctx.search.anchor)]}
                      for fl, w in modes)
    weights = ctx.search.weights if ctx.search is not None else ()
    cue_weights = {name: dict(w.to_info(), applied=bool(ctx.cfg.search.cue_weights))
                   for name, w in zip(("shadow", "photometric"), weights)}
    summary = FitSummary(shadow_blocks=float(n_eff), uncertainty_deg=float(spread), residual=residual,
                         pixels=len(pp.fp), exposure=exposure, note=note, unfixed=unfixed, modes=mode_info,
                         cue_weights=cue_weights, sky_share=float(share), misled=float(misled))
    direct = [*suns, *lamps]
    estimated = any((s.direction_from if isinstance(s, Sun) else s.position_from) in ESTIMATED for s in direct)
    source = "manifest" if (params.given and not estimated) else "estimated"
    shadows = ShadowKind.CAST if direct else ShadowKind.CONTACT
    return LightModel(suns=tuple(suns), lamps=tuple(lamps), sky=sky, shadows=shadows, source=source,
                      up_from=ctx.up_from, specular_roughness=pp.specular_roughness, probe=probe_ref, walls=pp.fp.walls,
                      fit=summary, anchor=pp.anchor)


__all__ = ["fit_light", "LightFit", "SUN_SHADING_PER_IRRADIANCE", "LAMP_SHADING_PER_WATT", "sh_world_to_camera",
           "sh_camera_to_world"]
