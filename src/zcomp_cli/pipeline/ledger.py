"""A job's ledger: every stage it went through, run or skipped (and why), and its time
(DESIGN.md section 6; issue 49). ``report.json`` carries it as ``stages``, a list in the
order the stages come:

* ``scene``: the photograph and its maps read (or kept from an earlier job of the
  scene); ``scene.maps``: each missing map estimated (or its estimate a cache hit), or
  skipped where every map is provided;
* ``object``: the object's intrinsic passes rendered by Blender, or a cache hit (Blender
  is not started when every pass of a batch is cached), or a bundle given, or a 2D
  object stood on the support;
* ``light`` and its steps (``light.ledger``): fitted, or a memory or cache hit; a given
  light is not searched (``light.search``), and one given whole builds no depth mesh
  (``light.shadows``); ``skipped`` for a renderer that draws no light;
* ``job.align``, ``job.composite``, ``job.shading_mask``, ``job.shading``: steps 1-4;
* ``render`` (both passes) and what the renderer says of its own: ``render.shadow_reach``
  (a given light's shadow followed past the mask, or why not), ``render.gloss`` and
  ``render.prefilter`` (the physical renderer's glossy reflection: nothing glossy, or
  the prefiltered sky built or kept from an earlier job), ``render.blender`` (the
  ``cycles`` renderer's Blender: started, or the batch's kept one);
* ``composite``: the compositor; ``write``: the outputs (added by the writer).

An entry is ``{"stage", "status": "run" | "skipped", "why", "seconds"[, "what"]}``.
"""

from __future__ import annotations

from zcomp_cli.light.ledger import entry


def scene_entries(scene, loaded: bool, load_s: float) -> list[dict]:
    """``scene`` and ``scene.maps`` (module docstring); ``loaded``: this job read it."""
    if not loaded:
        return [entry("scene", load_s, "loaded for an earlier job of the scene (kept until its last job)")]
    out = [entry("scene", load_s, what="the photograph and its provided maps read")]
    sources = getattr(scene, "sources", {}) or {}
    estimated = [m for m, src in sources.items() if m != "notes" and not str(src).startswith("provided")]
    if not estimated:
        out.append(entry("scene.maps", 0.0, "maps provided"))
        return out
    took = ((getattr(scene, "estimated", None) or {}).get("timings") or {})
    for m in estimated:
        s = took.get(m)
        out.append(entry(f"scene.maps.{m}", s, "cache hit (estimates/)" if s == 0.0 else None,
                         what=f"estimated: {sources[m]}"))
    return out


def object_entry(kind: str, rendered: dict | None, load_s: float) -> dict:
    """``object`` (module docstring): ``kind`` the manifest object's (mesh, bundle,
    image); ``rendered`` the object stage's word on a mesh job (``{"cached", "seconds"}``)."""
    if kind == "bundle":
        return entry("object", load_s, "bundle given (its passes are read, not rendered)")
    if kind == "image":
        return entry("object", load_s, what="a 2D object stood on the support")
    if rendered is not None and rendered.get("cached"):
        return entry("object", load_s, "cache hit (intrinsics/): Blender not asked for this pass")
    seconds = None if rendered is None else rendered.get("seconds")
    return entry("object", seconds, what="the object's passes rendered by Blender")


def render_entries(report: dict, timings: dict, glossy: bool) -> list[dict]:
    """``render`` and the renderer's own stages (module docstring), read off the job's
    report (the renderer's info and timings) and ``timings`` (the job's)."""
    r = report.get("renderer") or {}
    info, rt = r.get("info") or {}, r.get("timings") or {}
    name = (r.get("settings") or {}).get("name", "renderer")
    out = [entry("render", timings.get("render_s"), what=f"{name}: both passes")]
    light = info.get("light") if isinstance(info, dict) else None
    if isinstance(light, dict):
        out.append(_reach_entry(light, info.get("shadow"), report.get("shading_mask_grown_px"), rt.get("shadow_reach")))
    if name == "physical":
        out.append(entry("render.gloss", None, None if glossy else "nothing glossy (the object has no roughness map)",
                         what="the object's glossy reflection"))
        if "prefilter_built" in rt:
            out.append(entry("render.prefilter", rt["prefilter_built"], what="the sky's glossy prefilter built"))
        else:
            out.append(entry("render.prefilter", 0.0, "built for an earlier job of the scene (process memory)"
                             if glossy else "nothing glossy reads it"))
    passes = info.get("passes") if isinstance(info, dict) else None
    if name == "cycles" and isinstance(passes, list):
        start = next((p.get("blender_startup_s") for p in passes if p.get("blender_startup_s")), None)
        out.append(entry("render.blender", start, None if start else "the batch's Blender process, started earlier",
                         what="Blender started"))
    return out


def _reach_entry(light: dict, shadow, grown_px, seconds) -> dict:
    """``render.shadow_reach``: a given light's shadow of the object followed past the
    shading mask (``renderers.lighting.request_reach``), or why not."""
    if light.get("source") != "manifest":
        return entry("render.shadow_reach", seconds, "light estimated: its shadow fades at the shading mask's edge")
    if shadow != "cast shadow":
        return entry("render.shadow_reach", seconds, "no cast shadow (the contact shadow only)")
    what = (f"the mask grown by {grown_px} px along the object's shadow" if grown_px
            else "the object's shadow falls inside the shading mask")
    return entry("render.shadow_reach", seconds, what=what)


def job_ledger(report: dict, *, scene, loaded: bool, object_kind: str, rendered: dict | None, light: list | None,
               glossy: bool) -> list[dict]:
    """The job's ledger but its ``write`` (module docstring), from its report (its
    ``timings`` and the renderer's info), the scene, whether this job loaded it, the
    object's kind and stage, the light stage's entries (``light.ledger.light_entries``;
    None: the renderer draws no light) and whether the object is glossy."""
    t = report.get("timings") or {}
    out = scene_entries(scene, loaded, t.get("scene_load_s", 0.0))
    out.append(object_entry(object_kind, rendered, t.get("object_load_s", 0.0)))
    out += light if light is not None else [entry("light", 0.0, "the renderer draws no light of its own")]
    for stage, key in (("job.align", "align_s"), ("job.composite", "composite_intrinsics_s"),
                       ("job.shading_mask", "shading_mask_s"), ("job.shading", "shading_s")):
        out.append(entry(stage, t.get(key)))
    out += render_entries(report, t, glossy)
    out.append(entry("composite", t.get("compositor_s")))
    return out


def fit_share(stages: list[dict]) -> dict:
    """The seconds of a ledger's light stage (the job's fitting) and of the whole job
    (its stages summed), and the share: what ``benchmarks/bench_stage_ledger.py`` prints."""
    top = [e for e in stages if "." not in e["stage"]]
    total = sum(e["seconds"] or 0.0 for e in top)
    light = sum(e["seconds"] or 0.0 for e in top if e["stage"] == "light")
    return {"light_s": light, "total_s": total, "share": light / total if total > 0 else float("nan")}


__all__ = ["job_ledger", "scene_entries", "object_entry", "render_entries", "fit_share"]
