"""Where each archive keeps its cases, background maps, lights and shadows.

ZeroComp's test set (``labo.zip``, read by ``data/dataset_labo.py``)::

    <root>/<case>/<case>_bundle0001.exr
    <root>/<case>/<case>_bg_depth.exr   _bg_normal.png   _bg_diffuse.png
                  _bg_roughness.png   _bg_metallic.png            (each optional)

SpotLight's (its README's downloads; ``src/zerocomp/data/dataset_render.py``,
``src/spotlight/main_generate_shadows.py``)::

    <root>/<case>/<case>_bundle0001.exr
    <root>/<case>/<case>_light_path_dto.json
    <estimates>/<case>/<case>_bg_depth.exr ... (WACV_bg_estimates.zip)
    <shadows>/<case>/shadow_positive_<frame>.png ... (shadows.zip)

Cases are the ``*/*bundle*.exr`` files, sorted (the loaders' ``sorted(glob(...))``); a
case is named by its file with ``_bundle0001.exr`` removed. A sub-folder of the root
without a bundle is a partial case, reported as such.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from zcomp_cli.errors import UsageError

# map -> file suffix after the case name (load_image(..., isGamma=False) / ezexr.imread)
BG_MAP_SUFFIX = {"depth": "_bg_depth.exr", "normals": "_bg_normal.png", "albedo": "_bg_diffuse.png",
                 "roughness": "_bg_roughness.png", "metallic": "_bg_metallic.png"}
LIGHT_SUFFIX = "_light_path_dto.json"
SPOTLIGHT_ESTIMATES = "WACV_bg_estimates"
SPOTLIGHT_SHADOWS = "shadows"
_BUNDLE_RE = re.compile(r"^(?P<name>.+?)_bundle\d*\.exr$", re.IGNORECASE)


@dataclass
class CaseFiles:
    """One case's files (``None`` / absent keys where the archive lacks them)."""

    name: str
    folder: Path
    bundle: Path | None = None
    maps: dict[str, Path] = field(default_factory=dict)
    light: Path | None = None
    shadows: list[Path] = field(default_factory=list)
    problem: str | None = None  # a partial case: why it cannot be read


def case_name(bundle: Path) -> str:
    """``9C4A_crop_B07_bundle0001.exr`` -> ``9C4A_crop_B07``."""
    m = _BUNDLE_RE.match(bundle.name)
    return m.group("name") if m else bundle.stem


def _present(p: Path) -> bool:
    """Something other than a folder is there (a FIFO or a device too: the importer
    says what it is instead of "not found", and never opens it)."""
    return p.exists() and not p.is_dir()


def _bundles(folder: Path) -> list[Path]:
    return sorted(p for p in folder.glob("*bundle*.exr") if _present(p) and not p.name.startswith("."))


def case_root(root) -> Path:
    """The folder holding the case folders: ``root`` itself, or its one sub-folder that
    does (``labo/`` -> ``labo/GT_emission_envmap/``). UsageError when neither."""
    root = Path(root)
    if not root.is_dir():
        raise UsageError(f"{root} is not a folder")

    def holds_cases(d: Path) -> bool:
        return any(_bundles(c) for c in d.iterdir() if c.is_dir() and not c.name.startswith("."))

    if holds_cases(root):
        return root
    inner = [d for d in sorted(root.iterdir()) if d.is_dir() and not d.name.startswith(".") and holds_cases(d)]
    if len(inner) == 1:
        return inner[0]
    if len(inner) > 1:
        raise UsageError(f"{root} holds several case folders ({', '.join(d.name for d in inner)}): "
                         "give the one to import")
    raise UsageError(f"no case found under {root}: expected <case>/<case>_bundle0001.exr files "
                     "(the official archives' layout, see docs/reproduce.md)")


def list_cases(root: Path, maps_dir=None, light: bool = False, shadows_dir=None) -> list[CaseFiles]:
    """Every case under ``root`` (see ``case_root``), sorted by name.

    Args:
        root: the folder of case folders.
        maps_dir: ``None``: background maps beside each bundle (ZeroComp); else a folder
            of ``<case>/<case>_bg_*`` (SpotLight's WACV_bg_estimates).
        light: look for ``<case>_light_path_dto.json`` beside the bundle.
        shadows_dir: a folder of ``<case>/shadow_*.png`` (recorded, not used to render).
    """
    out: list[CaseFiles] = []
    for folder in sorted(d for d in root.iterdir() if d.is_dir() and not d.name.startswith(".")):
        if (folder / "import.json").is_file():
            continue  # an earlier zcomp import written into the archive's folder, not a case
        bundles = _bundles(folder)
        if not bundles:
            out.append(CaseFiles(folder.name, folder, problem=f"no *_bundle*.exr in {folder} (a partial case)"))
            continue
        for b in bundles:
            name = case_name(b)
            files = CaseFiles(name, folder, bundle=b)
            mdir = folder if maps_dir is None else Path(maps_dir) / name
            for m, suffix in BG_MAP_SUFFIX.items():
                p = mdir / f"{name}{suffix}"
                if _present(p):
                    files.maps[m] = p
            if light:
                p = folder / f"{name}{LIGHT_SUFFIX}"
                files.light = p if _present(p) else None
            if shadows_dir is not None and (Path(shadows_dir) / name).is_dir():
                files.shadows = sorted((Path(shadows_dir) / name).glob("shadow_*.png"))
            out.append(files)
    out.sort(key=lambda c: c.name)
    return out


def spotlight_sibling(root: Path, given, default_name: str) -> Path | None:
    """SpotLight's other downloads: ``given``, else ``<root>/<name>`` or a ``<name>``
    folder beside the root or beside its parent (``data/``), else None."""
    if given is not None:
        return Path(given)
    for cand in (root / default_name, root.parent / default_name, root.parent.parent / default_name):
        if cand.is_dir():
            return cand
    return None
