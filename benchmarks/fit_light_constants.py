"""Fit the light estimate's calibrated constants on the development seeds
(``seeds.DEVELOPMENT``), and print how each was chosen:

* ``search.prior_sky_share``: the sky's share of the support's light where the
  photograph does not tell it: the median, over the development cases, of the true share
  of the floor's irradiance at the object's base that the HDR map's sky brings (its sun
  and the lamps being the lights), from the generator's own description of each case;
* ``search.prior_sky_share_spread``: that share's spread over the same cases (the
  median absolute deviation x 1.4826): the prior's weight against the shadows'
  measurement of the split;
* ``search.temperature``: the posterior's one temperature. Every development case's background
  goes through the estimate's search once (``estimate.search``: the untempered
  log-likelihood of every direction it scores); for each value of ``--grid`` the
  posterior is tempered with it and scored by the **log score** of the true direction
  (the log posterior density at the dominant true light reaching the object's base,
  or at the nearest light whose cast shadows the background shows; an area lamp's
  direction as the search states it, from the point it hangs its lamps from) -- a proper scoring
  rule: it is best in expectation for the posterior that states the true uncertainty.
  The value with the best mean log score over the cases with a true light is chosen;
* ``search.photo_weight``: the photometric likelihood's independent observations per
  held-out block, with the temperature: the search runs once per value of
  ``--photo-grid`` (it decides which lamps are scored), and the pair with the best mean
  log score is chosen;
* ``search.elevation_prior_power``: the prior's density over directions, ``cos(elevation)
  ** -power`` per steradian, each power of ``--prior-grid`` scored with every weight and
  temperature.

The temperatures and powers of the grids are scored on the directions of each weight's
search, which ran at the default temperature and power (its lamp screening and its
refinement follow them): an approximation, off by up to 0.1 in the mean log score away
from the defaults. ``--exact W,T,P ...`` scores given triples exactly (the search run at
each; a minute or two apiece), and the best of those is chosen.

    python benchmarks/fit_light_constants.py BENCH_1618 BENCH_7777 [...] \
        [--grid 1,2,5,10,20,50,100] [--photo-grid 1,2,4,8] [--prior-grid 0,0.5,1] \
        [--exact 0.3,20,1 1,30,0]

Each BENCH is a ``make-benchmark`` folder. The constants are built into a search
configuration (``settings.SearchConfig``, the others at their defaults: no source file is
edited) and printed; the defaults in ``settings.py`` are set from it by hand, with this
script's output kept in ``docs/fit_light_constants.txt``.
"""

from __future__ import annotations

import argparse
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


def case_posteriors(bench: Path, settings=None):
    """[(case id, the search's posterior (untempered parts kept), the true direction or
    None, whether the background shows cast shadows, the elevation prior's log density
    at power 1 on the posterior's directions)] of a benchmark's cases; the true
    direction is the nearest light whose shadows the background shows, else the dominant
    light reaching the object's base."""
    import numpy as np

    from audit_light import load_case_inputs
    from run_benchmark import case_truths
    from zcomp_cli.light import search as estimate
    from zcomp_cli.light.config import DEFAULT_LIGHT as DEFAULTS
    from zcomp_cli.light.prepare import prepare
    from zcomp_cli.scene.frame import scene_up

    settings = DEFAULTS if settings is None else settings
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
        anchor = estimate.caster_anchor(pp, s.evidence, settings.evidence)
        t = truths[case["id"]]
        lights = [x for x in t["lights"] if x["visible"]]
        ref = None
        if t["shown"]:
            ref = max(t["shown"], key=lambda x: float(np.asarray(x["direction"]) @ s.posterior.map_direction))
        elif lights:
            ref = lights[0]
        # (the prior's log density at power 1, to score other powers on the same grid)
        base_prior = estimate.log_elevation_prior(s.posterior.dirs, up, 1.0)
        out.append((case["id"], s.posterior, None if ref is None else true_direction(ref, anchor), bool(t["shown"]),
                    base_prior))
        print(f"  {bench.name}/{case['id']}", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("benches", nargs="+", type=Path)
    ap.add_argument("--grid", default="1,2,3,5,7,10,15,20,30,50,100", help="temperatures to score")
    ap.add_argument("--photo-grid", default="1,2,4,8", help="photometric weights to search with")
    ap.add_argument("--prior-grid", default="0,0.5,1", help="elevation prior powers to score (on each search's grid)")
    ap.add_argument("--exact", nargs="*", default=[], metavar="W,T,P",
                    help="photo weight, temperature, prior power triples scored exactly (the search run at each)")
    args = ap.parse_args(argv)
    import dataclasses

    from zcomp_cli.light.posterior import DirectionPosterior
    from zcomp_cli.light.config import DEFAULT_LIGHT as DEFAULTS, SearchConfig

    grid = [float(x) for x in args.grid.split(",") if x.strip()]
    photo_grid = [float(x) for x in args.photo_grid.split(",") if x.strip()]
    prior_grid = [float(x) for x in args.prior_grid.split(",") if x.strip()]
    shares = []
    for b in args.benches:
        cases = json.loads((b / "benchmark.json").read_text())["cases"]
        s = [true_sky_share(c) for c in cases]
        shares += s
        print(f"{b}: {len(cases)} cases, true sky share median {statistics.median(s):.3f}", flush=True)
    share = statistics.median(shares)
    spread = 1.4826 * statistics.median([abs(x - share) for x in shares])
    print(f"prior_sky_share = {share:.2f}  (median of {len(shares)} cases)")
    print(f"prior_sky_share_spread = {spread:.2f}  (1.4826 x their median absolute deviation)")
    uniform = -math.log(2 * math.pi)

    def posteriors(settings):
        posts = []
        for b in args.benches:
            posts += [p for p in case_posteriors(b, settings) if p[2] is not None]
        return posts

    scores = []
    for w in photo_grid:
        settings = dataclasses.replace(DEFAULTS, search=dataclasses.replace(DEFAULTS.search, photo_weight=w))
        posts = posteriors(settings)
        for k in prior_grid:
            for T in grid:
                # (another power than the default's is scored on this search's grid, whose
                # lamp screening and refinement followed the default's prior)
                ls = [DirectionPosterior.from_parts(p.dirs, p.loglik, k * bp, p.solid_angle, T).log_density(t)
                      for _, p, t, _, bp in posts]
                scores.append((statistics.mean(ls), w, T, k))
                # (not fitted on: where the score comes from, the cases whose background
                # shows cast shadows and the others)
                parts = [[x for x, q in zip(ls, posts) if q[3] is shown] for shown in (True, False)]
                part = ", ".join(f"{name} {statistics.mean(x):.3f} ({len(x)})"
                                 for name, x in zip(("shown", "not shown"), parts) if x)
                print(f"  PHOTO_WEIGHT {w:g} TEMPERATURE {T:g} PRIOR_POWER {k:g}: mean log score "
                      f"{statistics.mean(ls):.3f} over {len(ls)} cases (a uniform hemisphere: {uniform:.3f}; {part})",
                      flush=True)
    best = max(scores)
    if args.exact:
        exact = []
        for triple in args.exact:
            w, T, k = (float(x) for x in triple.split(","))
            search = dataclasses.replace(DEFAULTS.search, photo_weight=w, temperature=T, elevation_prior_power=k)
            posts = posteriors(dataclasses.replace(DEFAULTS, search=search))
            ls = [p.log_density(t) for _, p, t, _, _ in posts]
            exact.append((statistics.mean(ls), w, T, k))
            print(f"  EXACT PHOTO_WEIGHT {w:g} TEMPERATURE {T:g} PRIOR_POWER {k:g}: mean log score "
                  f"{statistics.mean(ls):.3f} over {len(ls)} cases", flush=True)
        best = max(exact)
    print(f"photo_weight = {best[1]:g}, temperature = {best[2]:g}, elevation_prior_power = {best[3]:g}")
    fitted = dataclasses.replace(SearchConfig(), prior_sky_share=round(share, 2),
                                 prior_sky_share_spread=round(spread, 2), photo_weight=best[1], temperature=best[2],
                                 elevation_prior_power=best[3])
    print(f"SearchConfig(prior_sky_share={fitted.prior_sky_share}, prior_sky_share_spread="
          f"{fitted.prior_sky_share_spread}, photo_weight={fitted.photo_weight:g}, "
          f"temperature={fitted.temperature:g}, elevation_prior_power={fitted.elevation_prior_power:g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
