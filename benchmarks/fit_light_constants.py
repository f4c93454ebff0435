"""Fit the light estimate's calibrated constants on generated development cases, and
check them on whole generator families held out of the fit:

* ``search.prior_sky_share``: the sky's share of the support's light where the
  photograph does not tell it: the median, over the fit cases, of the true share of the
  floor's irradiance at the object's base that the HDR map's sky brings (its sun and the
  lamps being the lights), from the generator's own description of each case;
* ``search.prior_sky_share_spread``: that share's spread over the same cases (the
  median absolute deviation x 1.4826): the prior's weight against the shadows'
  measurement of the split;
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


def case_searches(bench: Path, settings, cache: Path | None):
    """Per case of ``bench`` with a true light: a dict of the search's unweighted scores
    and weights (``Search.scored``, ``weights``, ``log_opt_prior``), its directions and
    their solid angles, the elevation prior's log density at power 1 on them, the true
    direction, the stratum and the families. Cached in ``cache`` when given."""
    import hashlib
    import pickle

    import numpy as np

    from audit_light import load_case_inputs
    from run_benchmark import case_truths
    from zcomp_cli.light import search as estimate
    from zcomp_cli.light.prepare import prepare
    from zcomp_cli.scene.frame import scene_up

    key = hashlib.sha256(repr((str(bench.resolve()), settings, _code())).encode()).hexdigest()[:16]
    path = None if cache is None else cache / f"{bench.name}-{key}.pkl"
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
        s, _ = estimate.search(pp, settings)
        t = truths[case["id"]]
        lights = [x for x in t["lights"] if x["visible"]]
        if t["shown"]:
            ref = max(t["shown"], key=lambda x: float(np.asarray(x["direction"]) @ s.posterior.map_direction))
        elif lights:
            ref = lights[0]
        else:
            continue
        kind = str(ref.get("kind", "")).upper()
        stratum = "shadows shown" if t["shown"] else ("lamp" if kind in ("AREA", "POINT", "SPOT") else "bare floor")
        out.append({"case": f"{bench.name}/{case['id']}", "scored": s.scored, "weights": s.weights,
                    "log_opt_prior": s.log_opt_prior, "dirs": s.posterior.dirs, "omega": s.posterior.solid_angle,
                    "base_prior": estimate.log_elevation_prior(s.posterior.dirs, up, 1.0),
                    "truth": true_direction(ref, s.anchor), "stratum": stratum, "case_desc": case})
        print(f"  {bench.name}/{case['id']}: weights {s.weights[0].k:.3g} (shadow), {s.weights[1].k:.3g} "
              f"(photometric)", flush=True)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(out))
        tmp.replace(path)
    return out


def posterior_of(rec: dict, T: float, gate: float, power: float, weighed: bool = True, misled: float = 0.0):
    """A case's posterior at temperature ``T``, gate ``gate`` and prior power ``power``,
    its cues at their measured weights (``weighed``) or at 1 each, mixed with the prior
    by ``misled`` (``posterior.with_misled``)."""
    import dataclasses

    from zcomp_cli.light.posterior import DirectionPosterior
    from zcomp_cli.light.search import weighted_marginal

    w = rec["weights"] if weighed else tuple(dataclasses.replace(x, k=1.0) for x in rec["weights"])
    marg, _ = weighted_marginal(rec["scored"], w, gate, T, rec["log_opt_prior"], rec["omega"])
    return DirectionPosterior.from_parts(rec["dirs"], marg, power * rec["base_prior"], rec["omega"], T, misled)


def coverage_lines(recs: list, T: float, gate: float, power: float, weighed: bool, misled: float) -> list[str]:
    """Per stratum: n, the coverage of the stated 50/68/90 % cones, the mean log score."""
    import numpy as np

    from audit_light import CONES, cone_deg

    lines = []
    for st in STRATA:
        sel = [r for r in recs if r["stratum"] == st]
        if not sel:
            continue
        inside = {q: 0 for q in CONES}
        ls = []
        for r in sel:
            post = posterior_of(r, T, gate, power, weighed, misled)
            ls.append(post.log_density(r["truth"]))
            to_mean = float(np.degrees(np.arccos(np.clip(post.mean_direction @ r["truth"], -1.0, 1.0))))
            for q in CONES:
                inside[q] += to_mean <= cone_deg(post, q)
        cov = ", ".join(f"{round(100 * q)} %: {100 * inside[q] / len(sel):.0f} %" for q in CONES)
        lines.append(f"    {st}: n={len(sel)}, the truth inside the stated cones {cov}; mean log score "
                     f"{statistics.mean(ls):.3f}")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("benches", nargs="+", type=Path)
    ap.add_argument("--grid", default="6,8,10,12,16,20,25,30", help="temperatures to score")
    ap.add_argument("--misled-grid", default="0,0.1,0.2,0.25,0.3,0.4",
                    help="chances that the cues mislead (the prior's share) to score")
    ap.add_argument("--gate-grid", default="0,0.01", help="gates to score")
    ap.add_argument("--prior-grid", default="0,0.5,1", help="elevation prior powers to score")
    ap.add_argument("--hold-out", nargs="*", default=["hdr=studio", "lamp=AREA", "shape=chair"],
                    metavar="FAMILY=A,B", help="generator families held out of the fit (hdr, lamp, shape)")
    ap.add_argument("--cache", type=Path, default=None, help="keep each benchmark's searches here")
    ap.add_argument("--check", nargs="*", type=Path, default=[], metavar="BENCH",
                    help="benchmarks never fitted on (a report seed): scored at the chosen constants only")
    args = ap.parse_args(argv)
    import dataclasses

    from zcomp_cli.light.config import DEFAULT_LIGHT as DEFAULTS, SearchConfig

    grid = [float(x) for x in args.grid.split(",") if x.strip()]
    gate_grid = [float(x) for x in args.gate_grid.split(",") if x.strip()]
    misled_grid = [float(x) for x in args.misled_grid.split(",") if x.strip()]
    prior_grid = [float(x) for x in args.prior_grid.split(",") if x.strip()]
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
    for weighed, power, gate, misled, T in itertools.product((True, False), prior_grid, gate_grid, misled_grid, grid):
        ls = [posterior_of(r, T, gate, power, weighed, misled).log_density(r["truth"]) for r in fit]
        scores.append((statistics.mean(ls), T, gate, power, weighed, misled))
        print(f"  CUE_WEIGHTS {'on' if weighed else 'off'} TEMPERATURE {T:g} MISLED {misled:g} GATE "
              f"{gate:g} PRIOR_POWER {power:g}: mean log score {statistics.mean(ls):.3f} over "
              f"{len(ls)} fit cases (a uniform hemisphere: {uniform:.3f})", flush=True)
    for weighed in (True, False):
        b = max(x for x in scores if x[4] is weighed)
        print(f"  the best with the cue weights {'on' if weighed else 'off'}: {b[0]:.3f} (temperature {b[1]:g}, "
              f"misled {b[5]:g}, gate {b[2]:g}, prior power {b[3]:g})")
    b = max(x for x in scores if x[5] == 0.0) if 0.0 in misled_grid else None
    if b is not None:
        print(f"  the best never misled (misled 0): {b[0]:.3f} (temperature {b[1]:g}, gate {b[2]:g}, prior power "
              f"{b[3]:g}, cue weights {'on' if b[4] else 'off'})")
    _, T, gate, power, weighed, misled = max(scores)
    print(f"cue_weights = {weighed}, temperature = {T:g}, misled = {misled:g}, gate = {gate:g}, "
          f"elevation_prior_power = {power:g}")
    for name, sel in (("fit cases", fit), ("held-out families", check)):
        if sel:
            ls = [posterior_of(r, T, gate, power, weighed, misled).log_density(r["truth"]) for r in sel]
            print(f"  {name}: n={len(sel)}, mean log score {statistics.mean(ls):.3f}")
            print("\n".join(coverage_lines(sel, T, gate, power, weighed, misled)))
    for b in args.check:
        sel = case_searches(b, DEFAULTS, args.cache)
        ls = [posterior_of(r, T, gate, power, weighed, misled).log_density(r["truth"]) for r in sel]
        print(f"  {b} (checked, not fitted on): n={len(sel)}, mean log score {statistics.mean(ls):.3f}")
        print("\n".join(coverage_lines(sel, T, gate, power, weighed, misled)))
    fitted = dataclasses.replace(SearchConfig(), prior_sky_share=round(share, 2),
                                 prior_sky_share_spread=round(spread, 2), temperature=T, gate=gate,
                                 elevation_prior_power=power, cue_weights=weighed, misled=misled)
    print(f"SearchConfig(prior_sky_share={fitted.prior_sky_share}, prior_sky_share_spread="
          f"{fitted.prior_sky_share_spread}, temperature={fitted.temperature:g}, misled={fitted.misled:g}, "
          f"cue_weights={fitted.cue_weights}, gate={fitted.gate:g}, "
          f"elevation_prior_power={fitted.elevation_prior_power:g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
