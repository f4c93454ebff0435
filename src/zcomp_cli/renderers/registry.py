"""The one table of renderers (no heavy imports: the CLI reads it to build its options).

Each entry names where the class lives (imported only when the renderer is built) and
the settings it offers as command-line flags. The manifest's ``renderer: {name: ...,
<setting>: ...}`` takes the same setting names as the renderer's constructor.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RendererOption:
    """A renderer setting offered as a command-line flag: ``--<flag>`` sets ``setting``."""

    setting: str
    flag: str
    type: type
    help: str
    metavar: str | None = None


@dataclass(frozen=True)
class RendererEntry:
    module: str
    cls: str
    summary: str
    options: tuple[RendererOption, ...] = ()


RENDERERS: dict[str, RendererEntry] = {
    "physical": RendererEntry(
        "zcomp_cli.renderers.physical", "PhysicalRenderer",
        "embedded default: light from the scene's own shading and shadows, no weights, CPU"),
    "zerocomp": RendererEntry(
        "zcomp_cli.renderers.zerocomp", "ZeroCompRenderer",
        "Stable Diffusion 2.1 + the official ZeroComp ControlNet (weights on disk)",
        options=(
            RendererOption("controlnet", "weights", str, "the ControlNet checkpoint directory (holding controlnet/)",
                           "DIR"),
            RendererOption("base", "base", str,
                           "the Stable Diffusion 2.1 base directory (unet, vae, text_encoder, scheduler)", "DIR"),
            RendererOption("steps", "steps", int, "DDIM steps (default 20)", "N"),
        )),
    "naive": RendererEntry(
        "zcomp_cli.renderers.naive", "NaiveRenderer",
        "baseline paste: albedo x mean scene shading, no shadow (benchmark rows)"),
}
