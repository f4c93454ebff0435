"""What every renderer that draws the scene's light shares: the fitted light of a job's
requests (the light stage's, ``zcomp_cli.light``), and where a given light's shadow of
the object falls beyond the shading mask (``scene.shadowreach``)."""

from __future__ import annotations

from typing import Sequence

from zcomp_cli.light.stage import FittedLight, LightInputs, SceneLight, clean
from zcomp_cli.renderers.base import RenderRequest
from zcomp_cli.scene.lightmodel import LightModel, ShadowKind


def request_light(req: RenderRequest, stage: SceneLight, seed: int) -> FittedLight:
    """The request's fitted light: the light stage's (``req.fitted_light``), else the
    ``stage``'s fit of the request's scene and tree (a caller who runs no batch)."""
    if req.fitted_light is not None:
        return req.fitted_light
    inputs = LightInputs.of(req.maps, req.shading, req.known, req.camera, req.scene_key)
    return stage.get(inputs, req.light, seed)


def request_reach(requests: Sequence[RenderRequest], model: LightModel, cfg):
    """``scene.shadowreach.shadow_reach`` of a job's requests under a given light (the
    light config ``cfg``'s march and reach), or (None, None) for an estimated one, or
    one that casts no shadow: the rule every renderer that draws the light keeps."""
    from zcomp_cli.scene.shadowreach import shadow_reach

    if model.source != "manifest" or model.shadows is not ShadowKind.CAST:
        return None, None
    passes = [(clean(r.maps.depth, 0.0, 1e6), clean(r.maps.normals, -1.0, 1.0), r.known, r.occluder)
              for r in requests]
    return shadow_reach(passes, requests[0].camera, model, march=cfg.march, cfg=cfg.reach)


__all__ = ["request_light", "request_reach"]
