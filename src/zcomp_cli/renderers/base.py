"""The renderer interface shared by ``physical`` and ``zerocomp`` (DESIGN.md section 5).

A job calls its renderer once with two requests, the background ``i_bg`` and the
composite ``i_comp``, which share the shading mask, the camera and the seed. The
renderer returns one linear RGB image per request.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from zcomp_cli.camera import Camera
from zcomp_cli.conventions import DEFAULT_SEED
from zcomp_cli.maps import SceneMaps


@dataclass
class RenderRequest:
    """One renderer pass.

    Attributes:
        maps: the (background or composite) intrinsic maps.
        shading: H x W x 3 linear shading (image / albedo, clamped to [1e-5, 1e3]);
            meaningful only where ``known``.
        known: H x W bool, True where the shading is known (outside the shading mask).
        camera: intrinsics of this view.
        roi: ``(x0, y0, x1, y1)`` pixel window (half-open) where the output is needed;
            ``None`` = the whole frame. Outside it the output must be finite but is
            not used.
        image: H x W x 3 linear background photograph (x_bg) for context, optional.
        scene_key: a key identifying the background scene (same key = same background),
            so a renderer may cache per-scene work such as lighting estimation.
        light: the scene's light tree from the manifest (``scene.lightparams.LightParams``:
            what is given frozen, what is left out free, the camera's tilt; built by
            ``pipeline/lightspec.py``); None when the manifest gives neither a light nor
            a tilt (the light is estimated).
        fitted_light: the scene's light as the light stage fitted it
            (``light.stage.FittedLight``: the model, the filled tree, the posterior);
            the batch fits it once per scene and hands it to every job. None: a
            renderer that draws a light runs the stage itself (``light.stage``).
        occluder: the object's posed mesh (``zcomp_cli.posed_mesh.PosedMesh``) on the
            composite request when the bundle references one, else None.
        coverage: H x W float in [0, 1], the inserted object's visible coverage on the
            composite request (None on the background's): where its own material
            (roughness, metallic) applies.
        object_maps: the inserted object's own maps (``SceneMaps``: aligned depth,
            normals, albedo, roughness, metallic; 0 off the object) on the composite
            request (None on the background's): ``maps`` blends the albedo with the
            coverage, and a renderer that shades a partly covered pixel's two surfaces
            apart takes the object's from here.
        debug: the job runs with ``--debug``: the renderer may return debug maps
            (``RenderOutput.debug_maps``); without it, it need not make any.
        aovs: the job runs with ``--aovs``: the renderer may return its own render passes
            (``RenderOutput.aov_layers``); without it, it need not make any.
    """

    maps: SceneMaps
    shading: np.ndarray
    known: np.ndarray
    camera: Camera
    roi: tuple[int, int, int, int] | None = None
    image: np.ndarray | None = None
    scene_key: str | None = None
    light: object | None = None
    fitted_light: object | None = None
    occluder: object | None = None
    coverage: np.ndarray | None = None
    object_maps: SceneMaps | None = None
    debug: bool = False
    aovs: bool = False


@dataclass
class RenderOutput:
    """Renderer result: one H x W x 3 linear RGB float32 image per request, plus
    ``info`` (settings, estimates and fallbacks for the job report) and ``timings``
    (seconds per stage).

    ``shading_mask``: optional (H, W) bool, the pixels the renderer re-shaded in every
    image, a superset of the requests' unknown pixels. A renderer that knows where the
    object's shadow falls (the physical one, from its light) grows the mask along it,
    so a long shadow is not cut at the shading mask's edge; the compositor then applies
    the shadow ratio over this mask. None = the requested mask.

    ``object_layers``: optional, one per image (None or missing for an image without
    one): (H, W, 3) linear, the inserted object's own radiance where the request's
    ``coverage`` is > 0. Given, the compositor takes the object from it (``m C layer``)
    and the image there is the surface behind the object (the shadow ratio read from
    it is the surface's): a partly covered pixel is ``m`` of the one and ``1 - m`` of
    the other, as a path tracer's pixel is. Without it the image is both (DESIGN.md
    section 2, equation 5), and the surface behind a partly covered pixel counts twice.

    ``debug_maps``: optional maps the renderer read or made (the physical renderer's
    light evidence), name -> (H, W) or (H, W, C) float array at the job's working
    resolution. With ``--debug`` the pipeline writes each as ``debug/<name>.exr`` and
    shows them on one sheet (``pipeline.outputs``); without it they are ignored. A name
    is lower-case letters, digits, ``_`` and ``-`` (no path, no extension), none of the
    pipeline's own maps (``outputs.DEBUG_MAPS``); a renderer declares the names it may
    use in its registry entry (``RendererEntry.debug_maps``), so that a job folder
    holding them is known as zcomp's."""

    images: list[np.ndarray]
    info: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    shading_mask: np.ndarray | None = None
    object_layers: list = field(default_factory=list)
    debug_maps: dict[str, np.ndarray] = field(default_factory=dict)
    aov_layers: dict[str, np.ndarray] = field(default_factory=dict)


class Renderer(ABC):
    """Maps intrinsics + shading mask to linear RGB. Implementations must be
    deterministic for a given seed and must never return non-finite pixels (raise
    ``NumericalError`` instead)."""

    name: str = "renderer"
    # whether it draws the scene's light (then the batch fits it once per scene, with
    # ``light_config()``, and hands it over as ``RenderRequest.fitted_light``)
    uses_light: bool = False

    def light_config(self):
        """The light stage's config this renderer's light is fitted with
        (``light.config.LightConfig``; None: it draws no light)."""
        return None

    @abstractmethod
    def render(self, requests: Sequence[RenderRequest], *, seed: int = DEFAULT_SEED) -> RenderOutput:
        """Render the requests of ONE job (typically [background, composite]) in one call.
        Each output image depends only on its own request and the seed, except that the
        region re-shaded may be grown to the union of what the requests need (then
        reported as ``RenderOutput.shading_mask``)."""

    def render_jobs(self, jobs: Sequence[Sequence[RenderRequest]], seeds: Sequence[int]) -> list[RenderOutput]:
        """Render several jobs' requests; ``jobs[i]`` is rendered with ``seeds[i]``.

        The result must equal ``[self.render(r, seed=s) for r, s in zip(jobs, seeds)]``;
        a renderer that can share work across jobs (a GPU batch) overrides this."""
        if len(jobs) != len(seeds):
            raise ValueError(f"render_jobs: {len(jobs)} jobs but {len(seeds)} seeds")
        return [self.render(reqs, seed=s) for reqs, s in zip(jobs, seeds)]

    def settings(self) -> dict:
        """Settings recorded in each job report (and part of cache keys)."""
        return {"name": self.name}

    def check(self) -> None:
        """Called once before a batch writes anything: raise (``WeightsError``,
        ``UsageError``) for what would fail every job, such as missing weights. Must be
        cheap: load nothing heavy here."""
