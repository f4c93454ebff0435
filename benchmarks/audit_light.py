"""Audit of the light estimate's objective (issue 37): per case of a benchmark seed, the
estimate's posterior at the **true** light and at the chosen one.

    PYTHONPATH=src python benchmarks/audit_light.py BENCH [BENCH ...] [--cases 0,3-5] [--json OUT.json]

(Another version is audited with its own tree first on ``PYTHONPATH``; it needs an
``light.fit.fit_light`` (``zcomp_cli.testing.estimate_light``) returning its model and a
``posterior.DirectionPosterior`` -- the version before this one's, its tempered
likelihood over its coarse suns, was given one for the closing note's table.)

For every case of each ``make-benchmark`` folder BENCH (the generator knows its light:
``run_benchmark.true_lights``), the scene's background goes through the physical
renderer's light estimate exactly as ``zcomp composite`` runs it (the scene's maps at the
manifest's working size, every valid pixel known), and the audit prints:

* ``truth``: the kind of the dominant true light reaching the object's base (its
  direction: toward it from the base; an area lamp from the base to its centre), and
  whether the background shows its cast shadows (``run_benchmark.cast_shadows_shown``);
  the posterior is scored at a lamp's direction from the point the search hangs its
  lamps from (``search.caster_anchor``), as ``fit_light_constants.py`` scores it;
* ``err``: the angle between the estimate's key direction and the dominant true light
  (for the cases that show cast shadows: the nearest light whose shadows are shown);
* ``logp@true`` / ``logp@est``: the posterior's log density (per steradian) at the true
  direction and at the chosen one (``DirectionPosterior.log_density``); ``rank``: the
  true direction's rank among the posterior's grid directions (1 = the best);
  ``mass15``: the posterior mass within 15 deg of the truth;
* ``miss``: for an estimate more than 15 deg off, *search* when the truth scores better
  than the chosen direction (the search did not find it) and *objective* when it scores
  worse (the posterior prefers a wrong light: the formulation is at fault);
* ``spread``: the stated uncertainty (the posterior's RMS angle), and how the light is
  drawn (a cast shadow from how many of the posterior's modes, the heaviest's share, and
  the light's radius with where it came from: ``sh`` read off the shadows, ``def`` the
  default, ``man`` forced);
* ``k_sh`` / ``k_ph``: each cue's weight in the search (the shadow's and the
  photometric likelihood's power, read off the case's own blocks: ``light/cueweight.py``);
* ``split/true``: the sun/sky split (the sky's share of the support's light) the fit
  tied its key light to (``*``: read off the shadows' shadowed/lit ratio, else the
  prior's) and the truth's at the object's base (the generator's HDR sky against its
  sun and lamps); in the summary also the share the drawn sky holds, all its lobes
  against the suns (``LightModel.ambient_share``: what a full shadow keeps), beside the
  truth;
* ``in50/68/90``: whether the truth lies inside the stated 50, 68 and 90 % cones (the
  smallest cones about the posterior's mean direction holding that much of its mass);
  in the summary, beside them, inside the 50, 68 and 90 % highest-density sets
  (``hpd_mass``: the region a multimodal posterior states).

At the end: the median error and the share of cases under 10 and 20 deg (all cases with
a true light reaching the object, and those showing cast shadows), the miss classes, per
stratum (shadows shown / bare floor / lamp) the coverage of the stated 50, 68 and 90 %
cones and highest-density sets beside the mean log score, the mean log score of the truth (the proper scoring rule the temperature is fitted with,
``fit_light_constants.py``), and Spearman's rank correlation between the stated
uncertainty and the error.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

MISS_DEG = 15.0


def parse_cases(spec: str | None) -> set[int] | None:
    if not spec:
        return None
    out: set[int] = set()
    for part in spec.split(","):
        a, _, b = part.partition("-")
        out.update(range(int(a), int(b or a) + 1))
    return out


def load_case_inputs(bench: Path, case_id: str):
    """(depth, normals, shading, known, albedo, camera, image) of a case's background as
    ``zcomp composite`` sees it (the manifest's working size)."""
    from zcomp_cli.compositing.shading import shading_from_image
    from zcomp_cli.conventions import valid_depth_mask
    from zcomp_cli.pipeline.manifest import load_manifest
    from zcomp_cli.pipeline.scene import load_scene

    man = load_manifest(bench / "jobs.yaml")
    sc = load_scene(man.scenes[case_id], man.defaults.resolution)
    m = sc.maps
    shading = shading_from_image(sc.image, m.albedo)
    known = valid_depth_mask(m.depth) & np.all(np.isfinite(shading), -1)
    return m.depth, m.normals, shading, known, m.albedo, sc.camera, sc.image


def angle_deg(a, b) -> float:
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    c = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12)
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def spearman(x, y) -> float:
    from scipy.stats import spearmanr

    if len(x) < 3:
        return float("nan")
    return float(spearmanr(x, y).statistic)


def cone_deg(post, mass: float) -> float:
    """The half-angle (degrees) of the smallest cone about ``post``'s mean direction that
    holds ``mass`` of it (the stated cone)."""
    ang = np.degrees(np.arccos(np.clip(post.dirs @ post.mean_direction, -1.0, 1.0)))
    order = np.argsort(ang)
    cum = np.cumsum(post.probabilities[order])
    return float(ang[order][min(int(np.searchsorted(cum, mass)), len(ang) - 1)])


def hpd_mass(post, direction) -> float:
    """The mass of the posterior's highest-density set that reaches ``direction``: the
    grid directions denser (mass over solid angle) than the one nearest ``direction``.
    The truth lies inside the stated ``q`` highest-density set when this is at most
    ``q``: the region a posterior states, however many modes it has (a cone about the
    mean direction takes in the prior's mass wherever the cues' own share, ``1 -
    misled``, is near ``q``). (On the grid's own densities: the kernel-smoothed density
    of ``log_density`` is higher at a grid direction, its own kernel's centre, than
    between them, which would count too much mass as denser.)"""
    p = np.asarray(post.probabilities, np.float64)
    dens = np.log(np.maximum(p, 1e-300)) - np.log(np.asarray(post.solid_angle, np.float64))
    near = int(np.argmax(post.dirs @ np.asarray(direction, np.float64)))
    return float(p[dens > dens[near]].sum())


CONES = (0.5, 0.68, 0.9)


def stratum(row: dict) -> str:
    """The audit's strata: the background shows cast shadows; a lamp lights the object;
    else a bare floor."""
    if row.get("shown"):
        return "shadows shown"
    return "lamp" if str(row.get("truth", "")).upper() in ("AREA", "POINT", "SPOT", "LAMP") else "bare floor"


def audit_case(bench: Path, case: dict, truth: dict, settings=None) -> dict:
    from zcomp_cli.scene.frame import scene_up
    from zcomp_cli.testing import estimate_light

    d, n, sh, known, albedo, cam, _ = load_case_inputs(bench, case["id"])
    valid = known & (d > 0) & (np.abs(np.linalg.norm(n, axis=-1) - 1) < 0.2)
    up, up_from = scene_up(None, n, valid)
    t0 = time.perf_counter()
    res = estimate_light(d, n, sh, known, albedo, cam, up=up, up_from=up_from, cfg=settings, with_fit=True)
    model, post = res.model, res.posterior
    secs = time.perf_counter() - t0
    row = {"case": case["id"], "seconds": secs, "shadow": getattr(model.shadows, "value", str(model.shadows)),
           "spread_deg": float(model.fit.uncertainty_deg),
           "shadow_blocks": float(getattr(model.fit, "shadow_blocks", float("nan")))}
    lights = [t for t in truth["lights"] if t["visible"]]
    shown = truth["shown"]
    row["truth"] = lights[0]["kind"] if lights else "-"
    row["shown"] = bool(shown)
    row["radius_deg"] = float(max([s.radius_deg for s in model.suns], default=float("nan")))
    direct = [*model.suns, *model.lamps]
    row["radius_from"] = direct[0].radius_from.code if direct else "-"
    modes = list(getattr(model.fit, "modes", ()) or ())
    row["modes"] = len(modes)
    row["share0"] = float(modes[0]["share"]) if modes else float("nan")
    cues = getattr(model.fit, "cue_weights", {}) or {}
    row["k_shadow"] = float(cues.get("shadow", {}).get("k", float("nan")))
    row["k_photo"] = float(cues.get("photometric", {}).get("k", float("nan")))
    # the sun/sky split: the estimate's (read off the shadows where it stood on some, else
    # the prior's) beside the truth's at the object's base (the generator's own lights)
    from fit_light_constants import true_sky_share

    row["split_est"] = float(getattr(model.fit, "sky_share", float("nan")))
    row["split_true"] = float(true_sky_share(case))
    row["split_read"] = bool(float(getattr(model.fit, "shadow_blocks", 0.0)) > 0)
    # and the sky's share as the composite draws it: every lobe of the fitted sky against
    # the suns on a floor facing up (a model with lamps: not stated, their light falls off)
    row["split_drawn"] = float(model.ambient_share()) if not model.lamps else float("nan")
    est = model.key_direction
    if est is None and post is not None:
        est = post.mean_direction
    row["est_dir"] = None if est is None else [float(v) for v in est]
    if not lights:
        return row
    ref = min(shown, key=lambda t: angle_deg(est, t["direction"])) if (shown and est is not None) else lights[0]
    true_dir = np.asarray(ref["direction"], np.float64)
    row["true_dir"] = true_dir.tolist()
    from run_benchmark import _true_radius_deg

    row["radius_true"] = float(_true_radius_deg(ref, case))
    row["err_deg"] = angle_deg(est, true_dir) if est is not None else float("nan")
    if post is not None:
        # (the posterior's directions are from the point the search hangs its lamps from:
        # a lamp's true direction from there, as fit_light_constants.py scores it)
        from fit_light_constants import true_direction

        anchor = (getattr(res, "diagnostics", None) or {}).get("search_anchor")
        if anchor is not None:
            true_dir = true_direction(ref, anchor)
        row["logp_true"] = float(post.log_density(true_dir))
        row["logp_est"] = float(post.log_density(np.asarray(est))) if est is not None else float("nan")
        row["rank"] = int(post.rank(true_dir))
        row["mass15"] = float(post.mass_within(true_dir, MISS_DEG))
        to_mean = angle_deg(post.mean_direction, true_dir)
        row["hpd_true"] = hpd_mass(post, true_dir)
        for q in CONES:
            row[f"in{round(100 * q)}"] = bool(to_mean <= cone_deg(post, q))
            row[f"hpd{round(100 * q)}"] = bool(row["hpd_true"] <= q)
        if row["err_deg"] > MISS_DEG:
            row["miss"] = "search" if row["logp_true"] > row["logp_est"] else "objective"
    return row


def summarise(rows: list[dict]) -> str:
    lines = []

    def block(name, sel):
        errs = [r["err_deg"] for r in sel if math.isfinite(r.get("err_deg", math.nan))]
        if not errs:
            return
        lines.append(f"{name}: n={len(errs)} median {statistics.median(errs):.1f} deg, "
                     f"<10 deg {100 * np.mean(np.array(errs) < 10):.0f} %, <20 deg {100 * np.mean(np.array(errs) < 20):.0f} %")

    block("all cases with a light reaching the object", [r for r in rows if r["truth"] != "-"])
    block("cases whose background shows cast shadows", [r for r in rows if r["shown"]])
    # the drawn radius where the direction is found (within 10 deg) on the shown shadows:
    # within a factor 2 of the truth's, or under 2 deg where the truth is under 1 deg
    sized = [r for r in rows if r["shown"] and r.get("err_deg", math.inf) <= 10 and
             math.isfinite(r.get("radius_true", math.nan)) and math.isfinite(r.get("radius_deg", math.nan))]
    if sized:
        ok = [(r["radius_deg"] < 2.0) if r["radius_true"] < 1.0 else (0.5 <= r["radius_deg"] / r["radius_true"] <= 2.0)
              for r in sized]
        lines.append(f"the drawn radius where the shown shadows' direction is within 10 deg: n={len(sized)}, right "
                     f"(within x2, or < 2 deg for a truth < 1 deg) {100 * np.mean(ok):.0f} %: "
                     + ", ".join(f"{r['radius_deg']:.2g}/{r['radius_true']:.2g}" for r in sized))
    misses = [r.get("miss") for r in rows if r.get("miss")]
    lines.append(f"misses (> {MISS_DEG:g} deg): {len(misses)}: search {misses.count('search')}, "
                 f"objective {misses.count('objective')}")
    for name in ("shadows shown", "bare floor", "lamp"):
        sel = [r for r in rows if stratum(r) == name and "in68" in r]
        if sel:
            cov = ", ".join(f"{round(100 * q)} %: {100 * np.mean([r[f'in{round(100 * q)}'] for r in sel]):.0f} %"
                            for q in CONES)
            hpd = ", ".join(f"{round(100 * q)} %: {100 * np.mean([r.get(f'hpd{round(100 * q)}') for r in sel]):.0f} %"
                            for q in CONES)
            lps = [r["logp_true"] for r in sel if math.isfinite(r.get("logp_true", math.nan))]
            lines.append(f"{name}: n={len(sel)}, the truth inside the stated cones {cov}; inside the highest-"
                         f"density sets {hpd}; mean log score "
                         f"{statistics.mean(lps):.3f}" if lps else f"{name}: n={len(sel)}, {cov}; {hpd}")
    for name, sel in (("read off the shadows", [r for r in rows if r.get("split_read")]),
                      ("the prior's (no tied shadow under the light)", [r for r in rows if not r.get("split_read")])):
        d = [abs(r["split_est"] - r["split_true"]) for r in sel if math.isfinite(r.get("split_est", math.nan))]
        if d:
            lines.append(f"the sun/sky split {name}: n={len(d)}, median |estimate - truth| {statistics.median(d):.3f}, "
                         f"within 0.1: {100 * np.mean(np.array(d) <= 0.1):.0f} %")
    drawn = [r["split_drawn"] - r["split_true"] for r in rows if math.isfinite(r.get("split_drawn", math.nan))]
    if drawn:
        lines.append(f"the sky's share as drawn (all its lobes against the suns; models without lamps): "
                     f"n={len(drawn)}, median |drawn - truth| {statistics.median(np.abs(drawn)):.3f}, "
                     f"median drawn - truth {statistics.median(drawn):+.3f}")
    lp = [r["logp_true"] for r in rows if math.isfinite(r.get("logp_true", math.nan))]
    if lp:
        lines.append(f"mean log score of the truth: {statistics.mean(lp):.3f} (log density per sr; uniform "
                     f"over the hemisphere: {-math.log(2 * math.pi):.3f})")
    pairs = [(r["spread_deg"], r["err_deg"]) for r in rows
             if math.isfinite(r.get("err_deg", math.nan)) and math.isfinite(r["spread_deg"])]
    if pairs:
        lines.append(f"Spearman(stated uncertainty, error) = {spearman(*zip(*pairs)):.2f} (n={len(pairs)})")
    secs = [r["seconds"] for r in rows]
    lines.append(f"estimate time: median {statistics.median(secs):.2f} s")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("benches", nargs="+", type=Path)
    ap.add_argument("--cases", default=None, help="case indices, e.g. 0,3-5")
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    args = ap.parse_args(argv)
    from run_benchmark import case_truths

    sel = parse_cases(args.cases)
    rows = []
    hdr = (f"{'case':<18} {'truth':<8} {'shown':<5} {'err':>6} {'logp@true':>9} {'logp@est':>9} {'rank':>5} "
           f"{'mass15':>6} {'miss':<9} {'spread':>6} {'k_sh':>6} {'k_ph':>6} {'split/true':>10} "
           f"{'drawn, in50/68/90':<24}")
    for bench in args.benches:
        bench_json = json.loads((bench / "benchmark.json").read_text())
        truths = case_truths(bench)
        print(f"\n{bench}\n{hdr}")
        for i, case in enumerate(bench_json["cases"]):
            if sel is not None and i not in sel:
                continue
            r = audit_case(bench, case, truths[case["id"]])
            r["bench"] = str(bench)
            rows.append(r)
            drawn = (f"cast x{r['modes']} ({r['share0']:.0%}), r={r['radius_deg']:.2g} {r['radius_from'][:3]}"
                     if r["shadow"] == "cast shadow" else "contact")
            drawn += " " + "".join("y" if r.get(f"in{round(100 * q)}") else "n" for q in CONES)
            f = lambda k, fmt: format(r[k], fmt) if isinstance(r.get(k), (int, float)) else "-"
            print(f"{r['case']:<18} {r['truth']:<8} {str(r['shown']):<5} {f('err_deg', '6.1f'):>6} "
                  f"{f('logp_true', '9.2f'):>9} {f('logp_est', '9.2f'):>9} {f('rank', 'd'):>5} "
                  f"{f('mass15', '6.2f'):>6} {r.get('miss', ''):<9} {r['spread_deg']:6.1f} {f('k_shadow', '6.3f'):>6} "
                  f"{f('k_photo', '6.3f'):>6} {r['split_est']:4.2f}{'*' if r['split_read'] else ' '}/"
                  f"{r['split_true']:4.2f} {drawn:<24}", flush=True)
    print("\n" + summarise(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
