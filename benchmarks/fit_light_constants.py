"""Fit the light estimate's calibrated constants on generated development cases, and
check them on whole generator families held out of the fit:

* ``search.prior_sky_share``: the sky's share of the support's light where the
  photograph does not tell it: the median, over the fit cases, of the true share of the
  floor's irradiance at the object's base that the HDR map's sky brings (its sun and the
  lamps being the lights), from the generator's own description of each case;
* ``search.prior_sky_share_spread``: that share's spread over the same cases (the
  median absolute deviation x 1.4826): the prior's weight against the shadows'
  measurement of the split;
* ``search.default_radius_odds`` (with ``--radius-odds-grid``): how much more likely
  (in tempered log-likelihood) another size must be than the Sun's for a sun to be
  drawn at it: the odds whose drawn suns' sizes are right (within a factor 2 of the
  truth, under 2 deg for a truth under 1 deg) in the most fit cases where the background
  shows the light's cast shadows and the drawn direction is within 10 deg of the truth
  (a lamp has no typical size and no odds: ``search.default_odds``; its sizes are
  printed beside);
* ``search.cue_weights``, ``search.temperature``, ``search.misled``, ``search.gate`` and
  ``search.elevation_prior_power``: whether each cue is weighed by the power its own
  blocks bear out (``light/cueweight.py``), and what the data fit around that: the
  temperature over the cues' correlated pixels, and the chance that they mislead
  together (the posterior mixed with the prior by that much: ``posterior.with_misled``;
  a bias every block shares, which a temperature alone can only answer by flattening
  every case). Every
  case's background goes through the search once (``search.search`` at the defaults:
  its unweighted scores ``Search.scored`` and the cues' measured weights); each choice
  of the grids (weights on or off, temperature, gate, power) turns them into a
  posterior (``search.weighted_marginal``) scored by the **log score** of the true
  direction (the log posterior density at the nearest light whose cast shadows the
  background shows, else the dominant true light reaching the object's base; an area
  lamp's direction as the search states it, from the point it hangs its lamps from) --
  a proper scoring rule: best in expectation for the posterior that states the true
  uncertainty. The choice with the best mean log score over the fit cases is chosen.
  (The grids are scored on the directions each case's search chose at the defaults:
  its lamp screening and refinement followed them.) Each choice is printed beside the
  best with ``misled`` 0 (the temperature alone).

The check: the cases of the held-out families (``--hold-out``: HDR maps, lamp kinds --
SUN, AREA, or none for a scene the HDR map alone lights --, object shapes; a case is
held out when any of its families is; default: the studio map, the area lamps, the
chairs) are never fitted on;
the script prints their mean log score at the chosen constants beside the fit cases',
and per stratum (shadows shown / bare floor / lamp) the coverage of the stated 50, 68
and 90 % cones (the share of cases whose true direction falls inside) on both.

    python benchmarks/fit_light_constants.py CALIB/1618 CALIB/7777 [...] \
        [--grid 6,8,10,12,16,20,25,30] [--misled-grid 0,0.1,0.2,0.25,0.3,0.4] \
        [--gate-grid 0,0.01] [--prior-grid 0,0.5,1] \
        [--hold-out hdr=studio lamp=AREA shape=chair] [--cache DIR] \
        [--check BENCH_REPORT ...]

Each CALIB is a ``make-benchmark`` folder (``gen_calibration.py`` makes them). A case's
search is kept in ``--cache`` (keyed by the benchmark, the search's configuration and
the light stage's code), so that a re-run -- more seeds, other grids -- scores only what is new.
The constants are printed; the defaults in ``light/config.py`` are set from them by
hand, with this script's output kept in ``docs/fit_light_constants.txt``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def true_sky_share(case: dict) -> float:
    """The HDR sky's share of the floor's irradiance at the case object's base."""
    import numpy as np

    from zcomp_cli.benchsuite.scenes import BenchScene, hdr_lights, lamp_rays, lamps_for_blender

    sc = BenchScene.from_dict(case["scene"])
    h = hdr_lights(sc)
    base = np.asarray(case["pose"]["position"], np.float64)
    lamps = 0.0
    for lp in lamps_for_blender(sc):
        d, _, e = lamp_rays(lp, base[None])
        lamps += float(e[0]) * max(float(d[0] @ sc.up), 0.0)
    sky, sun = h["sky_floor_irradiance"], h["sun_floor_irradiance"] + lamps
    return sky / max(sky + sun, 1e-12)


def true_direction(light: dict, anchor):
    """The direction the search's posterior states for a true light (``true_lights``
    item): a sun's own; an area lamp's seen from ``anchor``, the point the search hangs
    its lamps from (``estimate.caster_anchor``), not from the object's base."""
    import numpy as np

    pos = light.get("lamp", {}).get("position")
    if light["kind"] == "HDR-sun" or pos is None:
        return np.asarray(light["direction"], np.float64)
    d = np.asarray(pos, np.float64) - np.asarray(anchor, np.float64)
    return d / max(float(np.linalg.norm(d)), 1e-12)


STRATA = ("shadows shown", "bare floor", "lamp")


def families(case: dict) -> dict:
    """A case's generator families: its HDR map, its lamps' kinds, its object's shape."""
    sc = case.get("scene", {})
    return {"hdr": {str(sc.get("hdr"))}, "lamp": {str(lp.get("kind")) for lp in sc.get("lamps", [])} or {"none"},
            "shape": {str(case.get("object", {}).get("recipe", {}).get("shape"))}}


def held_out(case: dict, hold: dict) -> bool:
    fam = families(case)
    return any(fam[k] & v for k, v in hold.items())


def _code() -> str:
    """The light stage's code as its syntax trees, docstrings and comments left out:
    what a cached search depends on."""
    import ast

    import zcomp_cli.light as light_pkg

    out = []
    for f in sorted(Path(light_pkg.__file__).parent.glob("*.py")):
        tree = ast.parse(f.read_text())
        for node in ast.walk(tree):
            body = getattr(node, "body", None)
            if (isinstance(body, list) and body and isinstance(body[0], ast.Expr)
                    and isinstance(getattr(body[0], "value", None), ast.Constant)
                    and isinstance(body[0].value.value, str)):
                node.body = body[1:] or [ast.Pass()]
        out.append(ast.dump(tree))
    return "".join(out)


def _per_case(bench: Path, settings, cache: Path | None, tag: str, record):
    """``record(case, search, scorer, truth)`` (a dict, or None to skip the case) over the
    cases of ``bench`` whose background has enough pixels, each searched once at
    ``settings`` (``search.search``); the list kept in ``cache`` (keyed by the benchmark,
    ``tag``, the settings and the light stage's code) when given."""
    import hashlib
    import pickle

    import numpy as np

    from audit_light import load_case_inputs
    from run_benchmark import case_truths
    from zcomp_cli.light import search as estimate
    from zcomp_cli.light.prepare import prepare
    from zcomp_cli.scene.frame import scene_up

    what = (str(bench.resolve()), settings, _code())
    key = hashlib.sha256(repr(what if not tag else (tag, *what)).encode()).hexdigest()[:16]
    path = None if cache is None else cache / f"{bench.name}-{tag + '-' if tag else ''}{key}.pkl"
    if path is not None and path.is_file():
        return pickle.loads(path.read_bytes())
    truths = case_truths(bench)
    out = []
    for case in json.loads((bench / "benchmark.json").read_text())["cases"]:
        d, n, sh, known, albedo, cam, _ = load_case_inputs(bench, case["id"])
        valid = known & (d > 0) & (np.abs(np.linalg.norm(n, axis=-1) - 1) < 0.2)
        up, _ = scene_up(None, n, valid)
        pp = prepare(d, n, sh, known, albedo, cam, up, settings)
        if len(pp.fp) < settings.search.few_pixels:
            continue
        s, sc = estimate.search(pp, settings)
        rec = record(case, s, sc, truths[case["id"]], up)
        if rec is not None:
            out.append(rec)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(out))
        tmp.replace(path)
    return out


def _reference(truth: dict, toward):
    """The true light a case is scored against: the one whose cast shadows the
    background shows nearest ``toward`` (3,), else the dominant one reaching the
    object's base; None where none does."""
    import numpy as np

    lights = [x for x in truth["lights"] if x["visible"]]
    if truth["shown"]:
        return max(truth["shown"], key=lambda x: float(np.asarray(x["direction"]) @ toward))
    return lights[0] if lights else None


def case_searches(bench: Path, settings, cache: Path | None):
    """Per case of ``bench`` with a true light: a dict of the search's unweighted scores
    and weights (``Search.scored``, ``weights``, ``log_opt_prior``), its directions and
    their solid angles, the elevation prior's log density at power 1 on them, the true
    direction, the stratum and the families. Cached in ``cache`` when given."""
    from zcomp_cli.light import search as estimate

    def record(case, s, _sc, t, up):
        ref = _reference(t, s.posterior.map_direction)
        if ref is None:
            return None
        kind = str(ref.get("kind", "")).upper()
        stratum = "shadows shown" if t["shown"] else ("lamp" if kind in ("AREA", "POINT", "SPOT") else "bare floor")
        print(f"  {bench.name}/{case['id']}: weights {s.weights[0].k:.3g} (shadow), {s.weights[1].k:.3g} "
              f"(photometric)", flush=True)
        return {"case": f"{bench.name}/{case['id']}", "scored": s.scored, "weights": s.weights,
                "log_opt_prior": s.log_opt_prior, "dirs": s.posterior.dirs, "omega": s.posterior.solid_angle,
                "base_prior": estimate.log_elevation_prior(s.posterior.dirs, up, 1.0),
                "truth": true_direction(ref, s.anchor), "stratum": stratum, "case_desc": case}

    return _per_case(bench, settings, cache, "", record)


def case_radii(bench: Path, settings, cache: Path | None):
    """Per case of ``bench`` with a true light: the drawn light's candidate radii and
    their untempered log-likelihoods (``search.radius_scores`` at the posterior's
    heaviest mode, as ``chosen_radius`` scores them; ``ll_true``: the same light moved
    to the true direction, the size's oracle), the true light's radius
    (``run_benchmark._true_radius_deg``), the mode's angle from the true direction,
    whether the background shows the light's cast shadows, and the families. Cached in
    ``cache`` like ``case_searches``."""
    import dataclasses

    import numpy as np

    from run_benchmark import _true_radius_deg
    from zcomp_cli.light import search as estimate

    def record(case, s, sc, t, _up):
        fl = s.modes[0][0] if s.modes else s.light
        toward = estimate.light_direction(fl, s.anchor)
        ref = _reference(t, toward)
        if ref is None:
            return None
        radii, ll = estimate.radius_scores(sc, fl, s.anchor, settings, 0)
        td = true_direction(ref, s.anchor)
        # the same light toward the truth (a lamp at its distance along it)
        at_truth = dataclasses.replace(fl, param=td if fl.kind == "sun" else
                                       s.anchor + float(np.linalg.norm(fl.param - s.anchor)) * td)
        _, ll_true = estimate.radius_scores(sc, at_truth, s.anchor, settings, 0)
        err = float(np.degrees(np.arccos(np.clip(td @ toward, -1.0, 1.0))))
        rec = {"case": f"{bench.name}/{case['id']}", "kind": fl.kind, "radii": radii, "ll": ll, "ll_true": ll_true,
               "err_deg": err,
               "true_radius": float(_true_radius_deg(ref, case)), "shown": bool(t["shown"]), "case_desc": case}
        print(f"  {bench.name}/{case['id']}: {err:.1f} deg off, true radius {rec['true_radius']:.2f} deg", flush=True)
        return rec

    return _per_case(bench, settings, cache, "radii", record)


def radius_right(drawn: float, true: float) -> bool:
    """Issue 47's test of a drawn size: within a factor 2 of the truth, or under 2 deg
    where the truth is under 1 deg."""
    if true < 1.0:
        return drawn < 2.0
    return true / 2.0 <= drawn <= 2.0 * true


def _sizes_right(sel: list, T: float, odds: float, key: str = "ll") -> tuple[int, int, float]:
    """(right sizes, cases, mean |log2(drawn / true)| with sizes under 0.1 deg as 0.1)
    of the records ``sel`` drawn at ``odds`` from their scores ``key`` (``ll`` at the
    drawn direction, ``ll_true`` at the true one)."""
    import math

    from zcomp_cli.light.search import picked_radius

    drawn = [picked_radius(r["radii"], r[key], T, odds)[0] for r in sel]
    right = sum(radius_right(d, r["true_radius"]) for d, r in zip(drawn, sel))
    lr = [abs(math.log2(max(d, 0.1) / max(r["true_radius"], 0.1))) for d, r in zip(drawn, sel)]
    return right, len(sel), (statistics.mean(lr) if lr else float("nan"))


def radius_lines(recs: list, grid: list, T: float, hold: dict) -> tuple[float, list[str]]:
    """(the odds chosen, the lines printed), over the cases whose background shows the
    light's cast shadows and whose drawn direction is within 10 deg of the truth (where
    a size is read at all): per odds of ``grid``, the right sizes (``radius_right``) of
    the drawn suns on the fit cases and on the held-out ones, and the mean
    |log2(drawn / true)|; the odds with the most right sizes on the fit cases (then the
    least mean log ratio) are chosen. Beside them, the size's oracle: the right sizes and
    the likeliest radii of the same lights moved to the true direction (``ll_true``). The
    drawn lamps (no odds: ``search.default_odds``) are printed beside, at 0."""
    import collections

    import numpy as np

    pop = [r for r in recs if r["shown"] and r["err_deg"] <= 10.0]
    suns = [r for r in pop if r.get("kind", "sun") == "sun"]
    fit = [r for r in suns if not held_out(r["case_desc"], hold)]
    check = [r for r in suns if held_out(r["case_desc"], hold)]
    truth = [r for r in suns if "ll_true" in r]  # (a cache of the rounds before the oracle has none)
    lines, best = [], None
    for odds in grid:
        (fr, fn, fl), (cr, cn, cl) = _sizes_right(fit, T, odds), _sizes_right(check, T, odds)
        at_truth = ""
        if truth:
            tr, tn, tl = _sizes_right(truth, T, odds, "ll_true")
            at_truth = f"; all of them scored at the true direction {tr}/{tn} ({tl:.2f})"
        lines.append(f"  DEFAULT_RADIUS_ODDS {odds:g}: right sizes of the drawn suns {fr}/{fn} fit cases (mean "
                     f"|log2 ratio| {fl:.2f}), {cr}/{cn} held out ({cl:.2f}){at_truth}")
        key = (fr, -fl)
        if best is None or key > best[0]:
            best = (key, odds)
    if truth:  # where the size's error lives: the likeliest radius, at the drawn and at the true direction
        for name, key in (("drawn", "ll"), ("true", "ll_true")):
            c = collections.Counter(float(r["radii"][int(np.argmax(r[key]))]) for r in truth)
            lines.append(f"  the likeliest radius at the {name} direction (deg: cases): "
                         + ", ".join(f"{k:g}: {c[k]}" for k in sorted(c)) + " (the true radii: "
                         + ", ".join(f"{r['true_radius']:.2g}" for r in truth) + ")")
    lamps = [r for r in pop if r.get("kind") == "lamp"]
    for name, sel in (("fit cases", [r for r in lamps if not held_out(r["case_desc"], hold)]),
                      ("held out", [r for r in lamps if held_out(r["case_desc"], hold)])):
        if sel:
            right, n, lr = _sizes_right(sel, T, 0.0)
            lines.append(f"  the drawn lamps (no odds), {name}: right sizes {right}/{n} (mean |log2 ratio| {lr:.2f})")
    return (best[1] if best else 1.0), lines


def posterior_of(rec: dict, T: float, gate: float, power: float, weighed: bool = True, misled: float = 0.0,
                 photo: float = 1.0):
    """A case's posterior at temperature ``T``, gate ``gate`` and prior power ``power``,
    its cues at their measured weights (``weighed``) or at 1 each, the photometric cue's
    times ``photo`` (``search.photo_weight`` at ``photo`` times the one it was scored at:
    the photometric log-likelihood is linear in it), mixed with the prior by ``misled``
    (``posterior.with_misled``)."""
    import dataclasses

    from zcomp_cli.light.posterior import DirectionPosterior
    from zcomp_cli.light.search import weighted_marginal

    w = rec["weights"] if weighed else tuple(dataclasses.replace(x, k=1.0) for x in rec["weights"])
    if photo != 1.0:
        w = (w[0], dataclasses.replace(w[1], k=w[1].k * photo))
    marg, _ = weighted_marginal(rec["scored"], w, gate, T, rec["log_opt_prior"], rec["omega"])
    return DirectionPosterior.from_parts(rec["dirs"], marg, power * rec["base_prior"], rec["omega"], T, misled)


def coverage_lines(recs: list, T: float, gate: float, power: float, weighed: bool, misled: float,
                   photo: float = 1.0) -> list[str]:
    """Per stratum: n, the coverage of the stated 50/68/90 % cones and highest-density
    sets (``audit_light.hpd_mass``), the mean log score."""
    import numpy as np

    from audit_light import CONES, cone_deg, hpd_mass

    lines = []
    for st in STRATA:
        sel = [r for r in recs if r["stratum"] == st]
        if not sel:
            continue
        inside = {q: 0 for q in CONES}
        dense = {q: 0 for q in CONES}
        ls = []
        for r in sel:
            post = posterior_of(r, T, gate, power, weighed, misled, photo)
            ls.append(post.log_density(r["truth"]))
            to_mean = float(np.degrees(np.arccos(np.clip(post.mean_direction @ r["truth"], -1.0, 1.0))))
            m = hpd_mass(post, r["truth"])
            for q in CONES:
                inside[q] += to_mean <= cone_deg(post, q)
                dense[q] += m <= q
        cov = ", ".join(f"{round(100 * q)} %: {100 * inside[q] / len(sel):.0f} %" for q in CONES)
        hpd = ", ".join(f"{round(100 * q)} %: {100 * dense[q] / len(sel):.0f} %" for q in CONES)
        lines.append(f"    {st}: n={len(sel)}, the truth inside the stated cones {cov}; inside the highest-density "
                     f"sets {hpd}; mean log score {statistics.mean(ls):.3f}")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("benches", nargs="+", type=Path)
    ap.add_argument("--grid", default="6,8,10,12,16,20,25,30", help="temperatures to score")
    ap.add_argument("--misled-grid", default="0,0.1,0.2,0.25,0.3,0.4",
                    help="chances that the cues mislead (the prior's share) to score")
    ap.add_argument("--gate-grid", default="0,0.01", help="gates to score")
    ap.add_argument("--prior-grid", default="0,0.5,1", help="elevation prior powers to score")
    ap.add_argument("--photo-grid", default="",
                    help="photometric weights (search.photo_weight) to score, e.g. 0.5,1,2,4 (default: the one in "
                         "place only)")
    ap.add_argument("--hold-out", nargs="*", default=["hdr=studio", "lamp=AREA", "shape=chair"],
                    metavar="FAMILY=A,B", help="generator families held out of the fit (hdr, lamp, shape)")
    ap.add_argument("--cache", type=Path, default=None, help="keep each benchmark's searches here")
    ap.add_argument("--radius-odds-grid", default="",
                    help="also fit search.default_radius_odds: the odds to score (e.g. 0,0.25,0.5,1,2; each case's "
                         "search is run again for its radii, cached beside its searches)")
    ap.add_argument("--check", nargs="*", type=Path, default=[], metavar="BENCH",
                    help="benchmarks never fitted on (a report seed): scored at the chosen constants only")
    args = ap.parse_args(argv)
    import dataclasses

    from zcomp_cli.light.config import DEFAULT_LIGHT as DEFAULTS, SearchConfig

    grid = [float(x) for x in args.grid.split(",") if x.strip()]
    gate_grid = [float(x) for x in args.gate_grid.split(",") if x.strip()]
    misled_grid = [float(x) for x in args.misled_grid.split(",") if x.strip()]
    prior_grid = [float(x) for x in args.prior_grid.split(",") if x.strip()]
    pw0 = DEFAULTS.search.photo_weight  # the weight the cases' searches are scored at
    photo_grid = [float(x) for x in args.photo_grid.split(",") if x.strip()] or [pw0]
    hold = {}
    for spec in args.hold_out:
        fam, _, vals = spec.partition("=")
        if fam not in ("hdr", "lamp", "shape") or not vals:
            ap.error(f"--hold-out {spec!r}: expected hdr=..., lamp=... or shape=... with comma-separated values")
        hold[fam] = {v.strip() for v in vals.split(",") if v.strip()}
    shares, recs = [], []
    for b in args.benches:
        cases = json.loads((b / "benchmark.json").read_text())["cases"]
        s = [true_sky_share(c) for c in cases if not held_out(c, hold)]
        shares += s
        print(f"{b}: {len(cases)} cases ({len(s)} fitted on), true sky share median "
              f"{statistics.median(s) if s else float('nan'):.3f}", flush=True)
        recs += case_searches(b, DEFAULTS, args.cache)
    share = statistics.median(shares)
    spread = 1.4826 * statistics.median([abs(x - share) for x in shares])
    print(f"prior_sky_share = {share:.2f}  (median of {len(shares)} fit cases)")
    print(f"prior_sky_share_spread = {spread:.2f}  (1.4826 x their median absolute deviation)")
    fit = [r for r in recs if not held_out(r["case_desc"], hold)]
    check = [r for r in recs if held_out(r["case_desc"], hold)]
    print(f"cases with a true light: {len(fit)} fitted on, {len(check)} held out ({' '.join(args.hold_out)})")
    ks = sorted(r["weights"][0].k for r in recs), sorted(r["weights"][1].k for r in recs)
    for name, k in zip(("shadow", "photometric"), ks):
        print(f"  the {name} cue's weight over the cases: median {statistics.median(k):.3g}, "
              f"quartiles {k[len(k) // 4]:.3g} .. {k[3 * len(k) // 4]:.3g}, at the floor {sum(x <= 1e-3 for x in k)}")
    uniform = -math.log(2 * math.pi)
    scores = []
    for weighed, power, gate, misled, T, pw in itertools.product((True, False), prior_grid, gate_grid, misled_grid,
                                                                   grid, photo_grid):
        ls = [posterior_of(r, T, gate, power, weighed, misled, pw / pw0).log_density(r["truth"]) for r in fit]
        scores.append((statistics.mean(ls), T, gate, power, weighed, misled, pw))
        print(f"  CUE_WEIGHTS {'on' if weighed else 'off'} TEMPERATURE {T:g} MISLED {misled:g} GATE "
              f"{gate:g} PRIOR_POWER {power:g} PHOTO_WEIGHT {pw:g}: mean log score {statistics.mean(ls):.3f} over "
              f"{len(ls)} fit cases (a uniform hemisphere: {uniform:.3f})", flush=True)
    for weighed in (True, False):
        b = max(x for x in scores if x[4] is weighed)
        print(f"  the best with the cue weights {'on' if weighed else 'off'}: {b[0]:.3f} (temperature {b[1]:g}, "
              f"misled {b[5]:g}, gate {b[2]:g}, prior power {b[3]:g}, photometric weight {b[6]:g})")
    b = max(x for x in scores if x[5] == 0.0) if 0.0 in misled_grid else None
    if b is not None:
        print(f"  the best never misled (misled 0): {b[0]:.3f} (temperature {b[1]:g}, gate {b[2]:g}, prior power "
              f"{b[3]:g}, cue weights {'on' if b[4] else 'off'})")
    _, T, gate, power, weighed, misled, pw = max(scores)
    if len(photo_grid) > 1:
        for w in photo_grid:
            b = max(x for x in scores if x[6] == w)
            print(f"  the best at photometric weight {w:g}: {b[0]:.3f} (temperature {b[1]:g}, misled {b[5]:g})")
    print(f"cue_weights = {weighed}, temperature = {T:g}, misled = {misled:g}, gate = {gate:g}, "
          f"elevation_prior_power = {power:g}, photo_weight = {pw:g}")
    ph = pw / pw0
    for name, sel in (("fit cases", fit), ("held-out families", check)):
        if sel:
            ls = [posterior_of(r, T, gate, power, weighed, misled, ph).log_density(r["truth"]) for r in sel]
            print(f"  {name}: n={len(sel)}, mean log score {statistics.mean(ls):.3f}")
            print("\n".join(coverage_lines(sel, T, gate, power, weighed, misled, ph)))
    for b in args.check:
        sel = case_searches(b, DEFAULTS, args.cache)
        ls = [posterior_of(r, T, gate, power, weighed, misled, ph).log_density(r["truth"]) for r in sel]
        print(f"  {b} (checked, not fitted on): n={len(sel)}, mean log score {statistics.mean(ls):.3f}")
        print("\n".join(coverage_lines(sel, T, gate, power, weighed, misled, ph)))
    odds_grid = [float(x) for x in args.radius_odds_grid.split(",") if x.strip()]
    odds = SearchConfig().default_radius_odds
    if odds_grid:
        radii = [r for b in args.benches for r in case_radii(b, DEFAULTS, args.cache)]
        odds, lines = radius_lines(radii, odds_grid, T, hold)
        print("the drawn size (where the shadows show and the direction is within 10 deg):")
        print("\n".join(lines))
        print(f"default_radius_odds = {odds:g}")
    fitted = dataclasses.replace(SearchConfig(), prior_sky_share=round(share, 2),
                                 prior_sky_share_spread=round(spread, 2), temperature=T, gate=gate,
                                 elevation_prior_power=power, cue_weights=weighed, misled=misled,
                                 photo_weight=pw)
    print(f"SearchConfig(prior_sky_share={fitted.prior_sky_share}, prior_sky_share_spread="
          f"{fitted.prior_sky_share_spread}, temperature={fitted.temperature:g}, misled={fitted.misled:g}, "
          f"cue_weights={fitted.cue_weights}, gate={fitted.gate:g}, "
          f"elevation_prior_power={fitted.elevation_prior_power:g}, photo_weight={fitted.photo_weight:g}, "
          f"default_radius_odds={odds:g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
