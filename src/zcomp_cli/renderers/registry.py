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
    # settings that change speed, not results: left out of resume fingerprints
    speed_settings: tuple[str, ...] = ()


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
            RendererOption("batch_size", "batch-size", int,
                           "jobs per GPU batch, N jobs x 2 passes per UNet/ControlNet call "
                           "(default 4; docs/zerocomp.md, Throughput)", "N"),
            RendererOption("window", "window", str,
                           "square window the model sees: auto (default), center (official "
                           "centre crop) or roi (crop around the job's region)", "MODE"),
            RendererOption("dtype", "dtype", str,
                           "auto (bf16 on GPU, fp32 on CPU), bf16, fp16, fp32 or fp16-autocast "
                           "(the official setting)", "DTYPE"),
        ),
        speed_settings=("batch_size", "channels_last", "compile")),
    "naive": RendererEntry(
        "zcomp_cli.renderers.naive", "NaiveRenderer",
        "baseline paste: albedo x mean scene shading, no shadow (benchmark rows)"),
}
