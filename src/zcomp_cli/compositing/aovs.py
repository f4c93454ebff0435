"""Render passes (AOVs) of a composite, for a compositor to redo the differential render.

One multi-layer EXR per job (``--aovs``: ``OUT/<job>/aovs.exr``), channels named
``<layer>.<channel>`` as Nuke and Blender read them, all linear float32:

| layer | channels | what |
| --- | --- | --- |
| ``composite`` | R G B | the result, ``composite.exr`` |
| ``background`` | R G B | the plate x_bg |
| ``shadow`` | Y | the shadow/opacity ratio R' (1 off the shading mask) |
| ``object`` | R G B A | the object, premultiplied: ``m C f(i_comp)`` (``m C`` the renderer's object layer where it gives one), alpha ``m`` |
| ``render_bg`` | R G B | f(i_bg), the renderer's background pass |
| ``render_comp`` | R G B | f(i_comp), the renderer's composite pass |

A renderer may add passes of its own after these (``RenderOutput.aov_layers``; the
``cycles`` renderer's ``cycles_*`` layers: Cycles' light passes of the composite pass).

They recombine into the composite (equation 5, DESIGN.md section 2):

    composite = (1 - object.A) * shadow.Y * background + object.RGB
"""

from __future__ import annotations

import numpy as np

LAYERS = ("composite", "background", "shadow", "object", "render_bg", "render_comp")


def aov_layers(x_bg, f_bg, f_comp, ratio_blurred, obj_mask, balance, composite, f_object=None) -> dict:
    """The layers of the table above: ``{layer: (H, W, C) float32}``.

    Args:
        x_bg, f_bg, f_comp, composite: (H, W, 3) linear RGB.
        ratio_blurred: (H, W) R'. obj_mask: (H, W) coverage m in [0, 1].
        balance: (3,) the colour balance C.
        f_object: the renderer's object layer (``compositor.composite``), or None.
    """
    m = np.clip(np.asarray(obj_mask, np.float64), 0.0, 1.0)[..., None]
    C = np.asarray(balance, np.float64).reshape(1, 1, 3)
    obj = m * C * np.asarray(f_comp if f_object is None else f_object, np.float64)
    out = {"composite": composite, "background": x_bg, "shadow": np.asarray(ratio_blurred)[..., None],
           "object": np.concatenate([obj, m], -1), "render_bg": f_bg, "render_comp": f_comp}
    return {k: np.ascontiguousarray(np.asarray(v, np.float32)) for k, v in out.items()}


def channel_names(layers: dict) -> tuple[np.ndarray, list[str]]:
    """The layers as one (H, W, C) array and its ``<layer>.<channel>`` names: the table's
    layers, then a renderer's own (``RenderOutput.aov_layers``) in their order."""
    names, planes = [], []
    for name in [*LAYERS, *(k for k in layers if k not in LAYERS)]:
        a = layers[name]
        chans = {1: ("Y",), 3: ("R", "G", "B"), 4: ("R", "G", "B", "A")}[a.shape[-1]]
        names += [f"{name}.{c}" for c in chans]
        planes.append(a)
    return np.concatenate(planes, -1), names


def recombine(layers: dict) -> np.ndarray:
    """The composite from the layers (the module docstring's formula)."""
    o = layers["object"].astype(np.float64)
    return ((1.0 - o[..., 3:4]) * layers["shadow"].astype(np.float64) * layers["background"] + o[..., :3])


__all__ = ["LAYERS", "aov_layers", "channel_names", "recombine"]
