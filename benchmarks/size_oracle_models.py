"""Where the size's error lives, under other models of the shadow's pixels (issue 47).

``fit_light_constants.py --radius-odds-grid`` found that, with the light moved to the
true direction, the shadow likelihood still prefers a wide light (8-16 deg) where the
truth is the Sun's size. This script asks whether a better model of what a pixel of
the photograph sees takes that preference away. For each sun whose cast shadows the
background shows and whose drawn direction is within 10 deg of the truth, at the
**true** direction, every candidate radius (``search.radius_scores``' radii) is scored
by the search's own shadow fit (``shadowcast.shadow_fit``, its Gaussian log-likelihood
at the case's noise scale) over every receiver of the working grid (no stride), with
the light's visibility ``V`` modelled four ways:

* ``point``: rays from each pixel's centre over the light's cone (the search's own);
* ``footprint``: the rays' origins spread over the pixel's footprint on the support
  (a 4 x 4 grid across the pixel, paired with as many directions of the cone): a pixel
  of the photograph is its area's mean, a hard edge across it a grey;
* ``aligned``: the footprint's prediction, each block of ``--block-px`` pixels scored
  at its best whole-pixel shift within ``--shift-px`` (an outline the depth mesh puts a
  pixel or two off, as a caster's edge quantised to the grid, no longer reads as a
  penumbra);
* ``blurred``: the footprint's prediction seen through the photograph's own blur (a
  Gaussian of ``BLURS_PX`` pixels, or none: the likeliest at each radius): a render's
  pixel filter and denoiser, a camera's lens, widen every edge by the same pixels,
  where a light's penumbra grows with the caster's distance.

It prints each case's tempered log-likelihoods relative to the Sun's size and, per
model, how many drawn sizes are right (``fit_light_constants.radius_right``: within x2,
or < 2 deg for a truth < 1 deg) at the odds 0, 1 and ``search.default_radius_odds``:
over all the suns, and apart for those where the scored light's are the only cast
shadows the background shows and those where another light's show too (the generator's
sun lamp beside the HDR map's own sun: two shadows of each caster, and one disc to
cover them).

    PYTHONPATH=src python benchmarks/size_oracle_models.py CALIB/1618 CALIB/4242 [...] \\
        [--block-px 12] [--shift-px 2]

A diagnostic: nothing in the estimate reads it (docs/calibration-record.md records its
output).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

MODELS = ("point", "footprint", "aligned", "blurred")
# the photograph's own blur tried (Gaussian sigma, working-grid pixels; none is the
# footprint's model): from a render's pixel filter to a soft lens or a denoiser's smear
BLURS_PX = (0.5, 1.0, 1.5, 2.0, 3.0)


def footprint_visibility(caster, mesh, rec, direction, radius_deg: float, side: int = 4) -> np.ndarray:
    """(R,) the share of a sun of ``radius_deg`` toward ``direction`` each receiver's
    pixel sees past ``caster``: ``side`` x ``side`` origins across the pixel's footprint
    on the support (its neighbours' spacing, the part along the support's plane), each
    paired with one of as many directions of the sun's cone."""
    from zcomp_cli.scene.sampling import cone_directions

    k = side * side
    g = (np.arange(side) + 0.5) / side - 0.5
    offsets = np.array([(a, b) for a in g for b in g])[np.random.default_rng(1).permutation(k)]
    gy, gx = np.gradient(mesh.points, axis=(0, 1))
    up = mesh.up
    ex, ey = gx[rec.ys, rec.xs], gy[rec.ys, rec.xs]
    ex = np.nan_to_num(ex - (ex @ up)[:, None] * up)
    ey = np.nan_to_num(ey - (ey @ up)[:, None] * up)
    d = np.asarray(direction, np.float64)
    dirs = cone_directions(d, radius_deg, k, seed=0) if radius_deg > 0 else np.repeat(d[None], k, 0)
    vis = np.zeros(len(rec))
    for (a, b), dj in zip(offsets, dirs):
        vis += ~caster.occluded_grid(rec.origins + a * ex + b * ey, dj[None])[0]
    return vis / k


def aligned_share(rec, shape, resid: np.ndarray, pred: np.ndarray, block: int, shift: int) -> float:
    """The weighted mean squared residual with each ``block`` x ``block`` block of the
    frame scored at the whole-pixel shift of the prediction (within ``shift``) that fits
    it best: ``resid`` (R,) the fit's residuals, ``pred`` (R,) its prediction
    ``c (1 - V)``."""
    h, w = shape
    obs = np.full(shape, np.nan)
    obs[rec.ys, rec.xs] = pred + resid
    P = np.full(shape, np.nan)
    P[rec.ys, rec.xs] = pred
    W = np.zeros(shape)
    W[rec.ys, rec.xs] = np.maximum(rec.weight, 0.0)
    total = 0.0
    for y0 in range(0, h, block):
        for x0 in range(0, w, block):
            o, ww = obs[y0:y0 + block, x0:x0 + block], W[y0:y0 + block, x0:x0 + block]
            live = ww > 0
            if not live.any():
                continue
            best = None
            for dy in range(-shift, shift + 1):
                for dx in range(-shift, shift + 1):
                    ya, xa = y0 + dy, x0 + dx
                    if ya < 0 or xa < 0 or ya + o.shape[0] > h or xa + o.shape[1] > w:
                        continue
                    p = P[ya:ya + o.shape[0], xa:xa + o.shape[1]]
                    ok = live & np.isfinite(p)
                    if ok.sum() < 0.8 * live.sum():  # a shift that leaves the block's receivers
                        continue
                    e = float((ww[ok] * (o[ok] - p[ok]) ** 2).sum()) * live.sum() / ok.sum()
                    best = e if best is None else min(best, e)
            total += best if best is not None else 0.0
    return total / max(float(W.sum()), 1e-12)


def blurred_columns(rec, shape, V: np.ndarray) -> np.ndarray:
    """(R, 1 + len(BLURS_PX)) the receivers' visibility ``V`` (R,) as it is and seen
    through each of ``BLURS_PX``: a Gaussian over the frame, normalised over the
    receivers (what is not a receiver lends no value)."""
    import cv2

    ok = np.zeros(shape)
    ok[rec.ys, rec.xs] = 1.0
    g = np.zeros(shape)
    g[rec.ys, rec.xs] = V
    cols = [V]
    for b in BLURS_PX:
        num = cv2.GaussianBlur(g, (0, 0), b)
        den = cv2.GaussianBlur(ok, (0, 0), b)
        cols.append((num / np.maximum(den, 1e-9))[rec.ys, rec.xs])
    return np.stack(cols, 1)


def case_scores(case, s, sc, t, settings, block: int, shift: int):
    """A record of the case's models' log-likelihoods over the radii at the true
    direction, and how many lights' cast shadows its background shows; None where the
    case is not a shown-shadow sun within 10 deg."""
    from fit_light_constants import _reference, true_direction
    from run_benchmark import _true_radius_deg
    from zcomp_cli.light import search as estimate
    from zcomp_cli.light.shadowcast import receivers, shadow_fit
    from zcomp_cli.scene.sampling import cone_directions

    fl = s.modes[0][0] if s.modes else s.light
    if fl.kind != "sun" or not t["shown"]:
        return None
    toward = estimate.light_direction(fl, s.anchor)
    ref = _reference(t, toward)
    if ref is None:
        return None
    td = true_direction(ref, s.anchor)
    err = float(np.degrees(np.arccos(np.clip(td @ toward, -1.0, 1.0))))
    if err > 10.0:
        return None
    mesh, caster = sc.pp.grid.mesh, sc.pp.grid.caster
    rec = receivers(mesh, sc.evidence, max_receivers=mesh.shape[0] * mesh.shape[1],
                    bias_rel=settings.search.bias_rel, blocks=settings.frame.holdout_blocks)
    radii, _ = estimate.radius_scores(sc, fl, s.anchor, settings, 0)
    sig = max(float(sc.sigma), settings.search.sigma_min)
    ll = {m: [] for m in MODELS}
    for r in radii:
        dirs = cone_directions(td, r, settings.cone_samples, seed=0) if r > 0 else td[None]
        v_point = (~caster.occluded_grid(rec.origins, dirs)).mean(0)
        v_foot = footprint_visibility(caster, mesh, rec, td, r)
        for m, V in (("point", v_point), ("footprint", v_foot)):
            ll[m].append(float(shadow_fit(rec, V[:, None], settings.search).loglik(sig)[0]))
        f = shadow_fit(rec, v_foot[:, None], settings.search)
        pred = math.log(float(f.ratio[0])) * (1.0 - v_foot)
        share = aligned_share(rec, mesh.shape, f.resid[:, 0], pred, block, shift)
        ll["aligned"].append(-0.5 * f.blocks * share / sig ** 2)
        ll["blurred"].append(float(shadow_fit(rec, blurred_columns(rec, mesh.shape, v_foot),
                                              settings.search).loglik(sig).max()))
    return {"case": case["id"], "err_deg": err, "true_radius": float(_true_radius_deg(ref, case)),
            "shown": len(t["shown"]),
            "radii": tuple(radii), **{m: np.asarray(v) for m, v in ll.items()}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("benches", nargs="+", type=Path)
    ap.add_argument("--block-px", type=int, default=12, help="the aligned model's blocks (working-grid pixels)")
    ap.add_argument("--shift-px", type=int, default=2, help="the aligned model's largest shift (pixels)")
    args = ap.parse_args(argv)
    from fit_light_constants import _per_case, radius_right
    from zcomp_cli.light.config import DEFAULT_LIGHT
    from zcomp_cli.light.search import picked_radius

    settings = DEFAULT_LIGHT
    T = settings.search.temperature
    recs = []
    for bench in args.benches:
        print(f"== {bench}", flush=True)
        for r in _per_case(bench, settings, None, "",
                           lambda c, s, sc, t, up: case_scores(c, s, sc, t, settings, args.block_px, args.shift_px)):
            recs.append(r)
            print(f"  {bench.name}/{r['case']}: {r['err_deg']:.1f} deg off, true radius {r['true_radius']:.2f} deg, "
                  f"{r['shown']} light(s)' shadows shown; "
                  "radii " + " ".join(f"{x:g}" for x in r["radii"]) + "; tempered, from the Sun's: "
                  + " | ".join(f"{m} " + " ".join(f"{(v - r[m][0]) / T:.1f}" for v in r[m]) for m in MODELS),
                  flush=True)
    odds_grid = sorted({0.0, 1.0, float(settings.search.default_radius_odds)})
    groups = (("all", recs), ("one light's shadows shown", [r for r in recs if r["shown"] <= 1]),
              ("several lights' shadows shown", [r for r in recs if r["shown"] > 1]))
    for name, group in groups:
        print(f"right sizes at the true direction, {name}: {len(group)} suns (temperature {T:g}):")
        for m in MODELS:
            counts = []
            for odds in odds_grid:
                drawn = [picked_radius(r["radii"], r[m], T, odds)[0] for r in group]
                counts.append(f"odds {odds:g}: {sum(radius_right(d, r['true_radius']) for d, r in zip(drawn, group))}"
                              f"/{len(group)}")
            best = [float(r["radii"][int(np.argmax(r[m]))]) for r in group]
            print(f"  {m}: " + ", ".join(counts) + "; the likeliest radius (deg: cases) "
                  + ", ".join(f"{x:g}: {best.count(x)}" for x in sorted(set(best))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
