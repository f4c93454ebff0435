"""The estimator mappings a manifest may give for a scene's missing maps, and what each
key may hold: one table, read by the manifest's validation (every problem reported with
its line before anything runs) and by the estimators themselves.

    depth:   {proxy: ground_plane, camera_height, pitch_deg | horizon_row, ...}
             {model: DIR, ...}        a transformers depth model or a diffusers depth pipeline
    normals: {from: depth, discontinuity_threshold}                       (default)
             {model: DIR, frame, encoded, ...}                            a normals pipeline
    albedo:  {method: retinex, lum_threshold, white_balance, ...}         (default)
             {model: DIR, space, materials, ...}                          an intrinsics pipeline

Every ``{model: DIR}`` form also takes the pipeline settings of
``estimators.diffusion.PipelineSettings`` (steps, ensemble_size, processing_resolution,
seed, dtype, device, variant, batch_size) and ``pipeline`` (the diffusers class to run
a folder saved under another name).
"""

from __future__ import annotations

from zcomp_cli.estimators.diffusion import DTYPES, RUNNERS, PipelineSettings, settings_problems
from zcomp_cli.estimators.ground_plane import GROUND_PLANE_KEYS
from zcomp_cli.estimators.model_outputs import INTRINSIC_SPACES, NORMAL_FRAMES

__all__ = ["estimator_problems", "MODEL_KEYS", "GROUND_PLANE_KEYS", "DEPTH_OUTPUTS", "DEPTH_ALIGN"]

MODEL_KEYS = {"model", "pipeline", *PipelineSettings.KEYS}
DEPTH_OUTPUTS = ("metric", "disparity", "affine")
DEPTH_ALIGN = ("auto", "ground_plane", "normals", "median")
RETINEX_KEYS = {"method", "lum_threshold", "chroma_threshold", "shading_smooth_px", "percentile",
                "percentile_value", "white_balance"}
ALLOWED = {
    ("depth", "proxy"): GROUND_PLANE_KEYS,
    ("depth", "model"): MODEL_KEYS | GROUND_PLANE_KEYS - {"proxy"} | {"output", "median_depth", "median_depth_m",
                                                                       "align"},
    ("normals", "from"): {"from", "discontinuity_threshold"},
    ("normals", "model"): MODEL_KEYS | {"frame", "encoded", "agreement_threshold_deg"},
    ("albedo", "method"): RETINEX_KEYS,
    ("albedo", "model"): MODEL_KEYS | {"space", "materials", "target"},
}


def form_of(map_name: str, spec: dict) -> str:
    """Which form an estimator mapping has: 'model', 'proxy', 'from' or 'method'."""
    if "model" in spec:
        return "model"
    return {"depth": "proxy", "normals": "from", "albedo": "method"}.get(map_name, "model")


def _ground_plane_problems(spec: dict) -> list[tuple[str | None, str]]:
    """The ground plane's own checks (``GroundPlaneSpec``: pitch within [-89, 89], one of
    pitch and horizon, roll...), at validation: ``pitch_deg: -90`` passed it and stopped
    ``zcomp estimate`` at that scene."""
    from zcomp_cli.errors import InputError
    from zcomp_cli.estimators.ground_plane import GroundPlaneSpec

    try:
        GroundPlaneSpec.from_dict({k: v for k, v in spec.items() if k in GROUND_PLANE_KEYS})
    except InputError as exc:
        text = str(exc)
        return [(next((k for k in sorted(GROUND_PLANE_KEYS, key=len, reverse=True) if k in spec and k in text),
                      None), text)]
    return []


def _number(spec, k, out, *, positive=True):
    v = spec.get(k)
    if v is None:
        return
    if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or (positive and not v > 0):
        out.append((k, f"expected a {'positive ' if positive else ''}number, got {v!r}"))


def estimator_problems(map_name: str, spec) -> list[tuple[str | None, str]]:
    """Every problem of one estimator mapping, as (key or None, message). Pure: files are
    not checked here (the manifest resolves ``model`` against its folder)."""
    if not isinstance(spec, dict):
        return [(None, f"expected an estimator mapping, got {type(spec).__name__}")]
    form = form_of(map_name, spec)
    allowed = ALLOWED.get((map_name, form))
    if allowed is None:
        if map_name in ("roughness", "metallic"):
            return [(None, f"{map_name} is not estimated on its own: give a map file, or an albedo model "
                           "that predicts materials (albedo: {model: DIR}, e.g. Marigold's appearance model)")]
        return [(None, f"{map_name} cannot be estimated")]
    out: list[tuple[str | None, str]] = []
    for k in spec:
        if k not in allowed:
            out.append((k, f"unknown key for {map_name} {form} (allowed: {', '.join(sorted(allowed))})"))
    if form == "model":
        m = spec.get("model")
        if not isinstance(m, str) or not m or "\0" in m:
            out.append(("model", f"expected the folder of a saved model, got {m!r}"))
        p = spec.get("pipeline")
        if p is not None and p not in RUNNERS.values():
            out.append(("pipeline", f"expected one of {', '.join(RUNNERS.values())}, got {p!r}"))
        out += [(k, msg) for k, msg in settings_problems(spec) if k in spec]
    if map_name == "depth":
        if form == "proxy" and spec.get("proxy", "ground_plane") != "ground_plane":
            out.append(("proxy", f"unknown depth proxy {spec['proxy']!r} (use ground_plane)"))
        if form == "proxy" and "camera_height" not in spec and "camera_height_m" not in spec:
            out.append((None, "the ground-plane proxy needs camera_height (metres above the floor)"))
        if spec.get("output") is not None and spec["output"] not in DEPTH_OUTPUTS:
            out.append(("output", f"expected one of {', '.join(DEPTH_OUTPUTS)}, got {spec['output']!r}"))
        if spec.get("align") is not None and spec["align"] not in DEPTH_ALIGN:
            out.append(("align", f"expected one of {', '.join(DEPTH_ALIGN)}, got {spec['align']!r}"))
        if spec.get("align") == "ground_plane" and "camera_height" not in spec and "camera_height_m" not in spec:
            out.append(("align", "align: ground_plane needs the ground-plane keys (camera_height, pitch_deg)"))
        for k in ("camera_height", "camera_height_m", "median_depth", "median_depth_m", "backdrop_distance",
                  "backdrop_distance_m"):
            _number(spec, k, out)
        for k in ("pitch_deg", "roll_deg", "horizon_row"):
            _number(spec, k, out, positive=False)
        if not out and (form == "proxy" or spec.get("align") == "ground_plane"):
            out += _ground_plane_problems(spec)
    elif map_name == "normals":
        if form == "from" and spec.get("from", "depth") != "depth":
            out.append(("from", f"only 'from: depth' is supported, got {spec['from']!r}"))
        _number(spec, "discontinuity_threshold", out)
        _number(spec, "agreement_threshold_deg", out)
        fr = spec.get("frame")
        if fr is not None:
            from zcomp_cli.errors import InputError
            from zcomp_cli.estimators.model_outputs import parse_normal_frame

            try:
                parse_normal_frame(fr)
            except InputError as exc:
                out.append(("frame", f"{exc} (named frames: {', '.join(NORMAL_FRAMES)})"))
        if "encoded" in spec and not isinstance(spec["encoded"], bool):
            out.append(("encoded", f"expected true or false, got {spec['encoded']!r}"))
    elif map_name == "albedo":
        if form == "method" and spec.get("method", "retinex") != "retinex":
            out.append(("method", f"unknown albedo method {spec['method']!r} (use retinex)"))
        for k in RETINEX_KEYS - {"method", "white_balance"}:
            _number(spec, k, out)
        if "white_balance" in spec and not isinstance(spec["white_balance"], bool):
            out.append(("white_balance", f"expected true (the plate's colour in the shading) or false "
                                          f"(grey shading), got {spec['white_balance']!r}"))
        sp = spec.get("space")
        if sp is not None and sp not in ("auto", *INTRINSIC_SPACES):
            out.append(("space", f"expected auto, {', '.join(INTRINSIC_SPACES)}, got {sp!r}"))
        if "materials" in spec and not isinstance(spec["materials"], bool):
            out.append(("materials", f"expected true or false, got {spec['materials']!r}"))
        t = spec.get("target")
        if t is not None and not (isinstance(t, str) and t):
            out.append(("target", f"expected the name of a predicted target, got {t!r}"))
    return out


def check_estimator(map_name: str, spec) -> None:
    """Raise InputError listing the problems of an estimator mapping (runtime check for
    specs that did not come through a validated manifest)."""
    from zcomp_cli.errors import InputError

    probs = estimator_problems(map_name, spec)
    if probs:
        raise InputError(f"{map_name} estimator: " + "; ".join(f"{k}: {m}" if k else m for k, m in probs))


__all__ += ["check_estimator", "form_of", "DTYPES"]
