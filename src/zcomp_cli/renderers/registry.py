"""The one table of renderers (no heavy imports: the CLI reads it to build its options).

Each entry names where the class lives (imported only when the renderer is built) and
the settings it offers as command-line flags. The manifest's ``renderer: {name: ...,
<setting>: ...}`` takes the same setting names as the renderer's constructor.

The table is open: a package adds a renderer by declaring an entry point in the
``zcomp.renderers`` group (as rio's plugins add commands), named after the renderer::

    # the plugin's pyproject.toml
    [project.entry-points."zcomp.renderers"]
    toon = "zcomp_toon:ENTRY"        # a RendererEntry (cheap to import), or
    # toon = "zcomp_toon.renderer:ToonRenderer"   # the Renderer subclass itself

``RENDERERS`` holds the built-in renderers and every installed plugin (found on first
use). The renderer contract (``tests/test_renderer_contract.py``) runs on every entry,
plugins included, with their ``contract_settings``. A plugin that cannot be loaded, or
whose name or flags clash with zcomp's, is left out with a warning; zcomp goes on.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "zcomp.renderers"
NAME_RE = re.compile(r"[a-z0-9][a-z0-9_\-]*")


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
    # For the renderer contract: settings of a small, quick instance, and whether it
    # reproduces the known background exactly (analytic) or approximately (learned).
    contract_settings: dict = field(default_factory=dict, hash=False, compare=False)
    contract_exact: bool = True
    # where it comes from: "zcomp", or the entry point ("toon = zcomp_toon:ENTRY")
    source: str = "zcomp"
    # the names of the debug maps it may return (``RenderOutput.debug_maps``): with
    # --debug they are written as debug/<name>.exr, and a job folder holding them is
    # known as zcomp's (``pipeline.outputs.foreign_entries``)
    debug_maps: tuple[str, ...] = ()
    # peak memory of a job per pixel of its working size, KB (``limits``: the pixel
    # budget is set for 0.3; a costlier renderer's jobs get fewer pixels)
    kb_per_pixel: float = 0.3


BUILTIN_RENDERERS: dict[str, RendererEntry] = {
    "physical": RendererEntry(
        "zcomp_cli.renderers.physical", "PhysicalRenderer",
        "embedded default: light from the scene's own shading and shadows, no weights, CPU",
        debug_maps=("shadow_evidence", "shadow_confidence", "shadow_ratio", "casters")),
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
                           "(default 8; docs/zerocomp.md, Throughput)", "N"),
            RendererOption("window", "window", str,
                           "square window the model sees: auto (default), center (official "
                           "centre crop) or roi (crop around the job's region)", "MODE"),
            RendererOption("dtype", "dtype", str,
                           "auto (bf16 on GPU, fp32 on CPU), bf16, fp16, fp32 or fp16-autocast "
                           "(the official setting)", "DTYPE"),
        ),
        speed_settings=("batch_size", "channels_last", "compile"), contract_exact=False),
    "cycles": RendererEntry(
        "zcomp_cli.renderers.cycles", "CyclesRenderer",
        "Blender's path tracer on a mesh of the photograph's depth, lit by the given or estimated light (bpy)",
        options=(
            RendererOption("samples", "samples", int, "Cycles path samples per pixel (default 32)", "N"),
        ),
        speed_settings=("threads",), contract_settings={"samples": 4, "denoise": False},
        # a window as large as the frame meshes it whole: 3.0 GB (Blender; zcomp 2.6) for one
        # job at 2048 x 1536, a given sun; a window of 40 % of it, meshed finely around
        # it and coarsely elsewhere, 1.69 GB (zcomp 1.46). Budgeted by the worst case.
        kb_per_pixel=1.0),
    "naive": RendererEntry(
        "zcomp_cli.renderers.naive", "NaiveRenderer",
        "baseline paste: albedo x mean scene shading, no shadow (benchmark rows)"),
}


def _entry_of(ep, obj) -> RendererEntry:
    """A plugin's entry: the ``RendererEntry`` it exports, or one built from its
    ``Renderer`` subclass (summary: the docstring's first line; ``cli_options``,
    ``speed_settings``, ``contract_settings``, ``contract_exact``, ``debug_maps`` class
    attributes)."""
    from dataclasses import replace

    if isinstance(obj, RendererEntry):
        return replace(obj, source=f"{ep.name} = {ep.value}")
    if isinstance(obj, type):
        from zcomp_cli.renderers.base import Renderer

        if not issubclass(obj, Renderer):
            raise TypeError(f"{obj.__qualname__} is not a zcomp Renderer subclass")
        doc = (obj.__doc__ or "").strip().splitlines()
        return RendererEntry(obj.__module__, obj.__qualname__, doc[0] if doc else f"plugin renderer {ep.name}",
                             options=tuple(getattr(obj, "cli_options", ())),
                             speed_settings=tuple(getattr(obj, "speed_settings", ())),
                             contract_settings=dict(getattr(obj, "contract_settings", {}) or {}),
                             contract_exact=bool(getattr(obj, "contract_exact", True)),
                             source=f"{ep.name} = {ep.value}",
                             debug_maps=tuple(getattr(obj, "debug_maps", ())))
    raise TypeError(f"expected a RendererEntry or a Renderer subclass, got {type(obj).__name__}")


def discover(builtin: Mapping[str, RendererEntry]) -> tuple[dict[str, RendererEntry], list[str]]:
    """The installed plugin renderers (entry point group ``zcomp.renderers``) and the
    problems of those left out."""
    from importlib.metadata import entry_points

    found: dict[str, RendererEntry] = {}
    problems: list[str] = []
    try:
        eps = list(entry_points(group=ENTRY_POINT_GROUP))
    except Exception as exc:  # noqa: BLE001 - a broken installation must not break zcomp
        return found, [f"cannot list {ENTRY_POINT_GROUP} entry points: {exc}"]
    for ep in sorted(eps, key=lambda e: e.name):
        what = f"renderer plugin {ep.name!r} ({ep.value})"
        if ep.name in builtin:
            problems.append(f"{what}: the name of a built-in renderer; left out")
            continue
        if not NAME_RE.fullmatch(ep.name) or ep.name in found:
            problems.append(f"{what}: a renderer name is lower-case letters, digits, '_' and '-', "
                            "once; left out")
            continue
        try:
            found[ep.name] = _entry_of(ep, ep.load())
        except BaseException as exc:  # noqa: BLE001 - one broken plugin must not break zcomp
            # a plugin whose import calls sys.exit() must not end zcomp (silently, exit 0);
            # Ctrl-C still interrupts
            if isinstance(exc, KeyboardInterrupt):
                raise
            problems.append(f"{what}: cannot be loaded ({type(exc).__name__}: {str(exc)[:300]}); left out")
    for p in problems:
        log.warning("%s", p)
    return found, problems


class RendererRegistry(Mapping):
    """``RENDERERS``: name -> ``RendererEntry``, the built-ins first, then the installed
    plugins (looked up once, on first use). ``problems`` lists plugins left out."""

    def __init__(self, builtin: Mapping[str, RendererEntry]):
        self._builtin = dict(builtin)
        self._all: dict[str, RendererEntry] | None = None
        self.problems: list[str] = []

    def _table(self) -> dict[str, RendererEntry]:
        if self._all is None:
            plugins, self.problems = discover(self._builtin)
            self._all = {**self._builtin, **plugins}
        return self._all

    def reload(self) -> None:
        """Look the plugins up again (after installing one in this process)."""
        self._all = None

    @property
    def builtin(self) -> dict[str, RendererEntry]:
        return dict(self._builtin)

    def __getitem__(self, name: str) -> RendererEntry:
        return self._table()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._table())

    def __len__(self) -> int:
        return len(self._table())

    def __repr__(self) -> str:
        return f"RendererRegistry({list(self)})"


RENDERERS = RendererRegistry(BUILTIN_RENDERERS)
