"""The light stage in a job's ledger (issue 49; DESIGN.md section 6: each job's report
says which stages ran, which were skipped and why, and their time).

While the fit runs, ``timed`` adds each step's seconds to a dict (``fit.fit_light``'s
``steps``: ``prepare`` -- the fit pixels, the sky's visibility, the bounce, the albedo's
offset, and within it ``shadows``, the depth mesh and its ray tracer --, ``probe`` -- a
given probe read and split into its sources and sky --, ``search``, ``lights`` -- the
given lights' and the sky's terms --, ``sizes``, ``solve``); ``light_entries`` turns a
fitted light (``stage.FittedLight``) into the job's ledger entries.

An entry is ``{"stage", "status": "run" | "skipped", "why", "seconds"}`` (``why``: None
where it ran; ``what`` says what a run did where that helps).
"""

from __future__ import annotations

import time
from contextlib import contextmanager


@contextmanager
def timed(steps: dict, name: str):
    """Add the block's seconds to ``steps[name]``."""
    t0 = time.perf_counter()
    try:
        yield
    finally:
        steps[name] = steps.get(name, 0.0) + time.perf_counter() - t0


def entry(stage: str, seconds: float | None = None, why: str | None = None, what: str | None = None) -> dict:
    """One ledger entry: run (``why`` None) or skipped (``why`` says why)."""
    out = {"stage": stage, "status": "run" if why is None else "skipped", "why": why,
           "seconds": None if seconds is None else round(float(seconds), 4)}
    if what:
        out["what"] = what
    return out


def light_entries(fitted, params, lookup_s: float) -> list[dict]:
    """The ledger entries of the light stage for a job: ``fitted`` the scene's fitted
    light (``stage.FittedLight``), ``params`` the tree it was asked for (None:
    estimated), ``lookup_s`` the seconds the job spent getting it. A fit this job did not
    run (a memory or cache hit) is one skipped entry; a fit it ran, one entry and its
    steps."""
    if fitted.how != "fitted":
        why = ("cache hit (fitted by an earlier run or worker)" if fitted.how == "cache"
               else "fitted for an earlier job of the scene (process memory)")
        return [entry("light", lookup_s, why)]
    given = params is not None and params.given
    steps = dict(getattr(fitted, "steps", None) or {})
    out = [entry("light", lookup_s, what=("a given light: its free values" if given else "estimated"))]
    prep = steps.get("prepare")
    shadows = steps.get("shadows")  # (built beside the rest of prepare: the entries sum to the wall time)
    out.append(entry("light.prepare", None if prep is None else prep - (shadows or 0.0),
                     what="fit pixels, the sky's visibility, the bounce, the specular layer"))
    out.append(entry("light.shadows", shadows, None if shadows is not None else
                     ("light given whole: no search, size choice or split reads the photograph's shadows"
                      if given else "too few known pixels to read shadows from"),
                     what="the depth mesh and its ray tracer"))
    if params is not None and params.probe is not None:
        out.append(entry("light.probe", steps.get("probe"), what="the given probe read and split"))
    out.append(entry("light.search", steps.get("search"),
                     None if "search" in steps else ("light given" if given else "too few known pixels")))
    if "lights" in steps:
        out.append(entry("light.terms", steps["lights"], what="the given lights' and the sky's terms"))
    out.append(entry("light.sizes", steps.get("sizes"), None if shadows is not None else
                     "sizes given (or too few known pixels to choose them)"))
    free = _free_values(fitted.params)
    out.append(entry("light.solve", steps.get("solve"), what=free))
    return out


def _free_values(params) -> str:
    """What the solve fitted, in words: the exposure alone where every strength is
    given in physical units, else the free strengths."""
    suns = [s for s in params.suns if not s.irradiance.frozen and s.share is None]
    lamps = [lp for lp in params.lamps if not lp.power.frozen]
    sky = params.probe is None and not params.sky.radiance_sh.frozen
    if not (suns or lamps or sky):
        return "the exposure only"
    parts = ([f"{len(suns)} sun strength(s)"] if suns else []) + ([f"{len(lamps)} lamp power(s)"] if lamps else [])
    return ", ".join(parts + (["the sky"] if sky else []))


__all__ = ["timed", "entry", "light_entries"]
