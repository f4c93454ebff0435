"""``zcomp import``: an official archive -> ``jobs.yaml`` + ``<stem>_data/<case>/``.

Per case, in ``<stem>_data/<case>/`` beside the manifest (written atomically, a failed
case leaves nothing):

* ``background.exr`` (the scene photo, linear), ``reference.exr`` (the ground-truth
  composite, linear), ``object_mask.png`` (the object's coverage: ``zcomp eval``'s object
  crop and shadow metrics read it beside the reference);
* ``object/``: a zcomp object bundle (depth, normals, albedo, mask, footprint_depth,
  roughness, metallic, meta.json), read from the multi-layer EXR without Blender;
* ``depth.exr``, ``normals.exr``, ``albedo.exr`` (+ ``roughness.exr``, ``metallic.exr``):
  the archive's background maps in zcomp's conventions, when ``--maps`` uses them;
* ``case.json``: the dataset, the source files, each conversion applied, the checks.

The manifest's jobs composite each case's object into its photo with the paper's
settings, ``reference:`` set to the ground truth. ``<stem>_data/import.json`` lists the
cases imported and those that failed (why). A case that cannot be read is reported and
the others go on.
"""

from __future__ import annotations

import fnmatch
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from zcomp_cli.datasets import lvsn
from zcomp_cli.datasets.bundle_exr import SPOTLIGHT_READING, ZEROCOMP_READING, BundleReading, read_bundle
from zcomp_cli.datasets.layouts import (SPOTLIGHT_ESTIMATES, SPOTLIGHT_SHADOWS, BG_MAP_SUFFIX, CaseFiles,
                                        case_root, list_cases, spotlight_sibling)
from zcomp_cli.errors import InputError, ManifestError, UsageError, ZcompError
from zcomp_cli.limits import printable
from zcomp_cli.metrics.published import CASE_FILE

MAPS_CHOICES = ("paper", "provided", "estimated")
IMPORT_FILE = "import.json"
_NAME_BAD = re.compile(r"[^A-Za-z0-9_.\-]")


@dataclass(frozen=True)
class Archive:
    """What differs between the two archives."""

    key: str                      # the command: "zerocomp" | "spotlight"
    title: str
    reading: BundleReading
    shading_radius: float
    has_lights: bool


ARCHIVES = {
    "zerocomp": Archive("zerocomp", "ZeroComp test set (labo)", ZEROCOMP_READING, lvsn.ZEROCOMP_SHADING_RADIUS, False),
    "spotlight": Archive("spotlight", "SpotLight test set", SPOTLIGHT_READING, lvsn.SPOTLIGHT_SHADING_RADIUS, True),
}


@dataclass
class ImportOptions:
    src: Path
    out: Path                          # the manifest to write
    maps: str = "paper"                # paper | provided | estimated
    depth_model: Path | None = None    # a transformers depth model (ZoeDepth for the paper)
    limit: int | None = None
    cases: str | None = None           # glob on case names
    overwrite: bool = False
    bundle_normals: str | None = None  # override the loader's normal frame
    lights: str = "gt"                 # SpotLight: gt | all | none
    estimates: Path | None = None      # SpotLight: WACV_bg_estimates
    shadows: Path | None = None        # SpotLight: shadows


@dataclass
class ImportResult:
    manifest: Path | None
    data_dir: Path
    root: Path
    imported: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    jobs: int = 0
    notes: list[str] = field(default_factory=list)


def data_dir_for(manifest: Path) -> Path:
    return manifest.parent / f"{manifest.stem}_data"


def check_options(archive: Archive, opts: ImportOptions) -> None:
    """Usage problems, found before anything is read or written (exit 2)."""
    if opts.maps not in MAPS_CHOICES:
        raise UsageError(f"--maps must be one of {', '.join(MAPS_CHOICES)}, got {opts.maps!r}")
    if opts.maps in ("paper", "estimated") and opts.depth_model is None:
        why = ("the paper ran ZoeDepth on each photo for the depth (configs/sg_labo.yaml: predictor_names "
               "[zoedepth, precompute_stablenormal, precompute])" if opts.maps == "paper"
               else "zcomp's estimators need a depth model for these photos")
        raise UsageError(f"--maps {opts.maps} needs --depth-model DIR: {why}. Give a local transformers "
                         "depth model (ZoeDepth NK: Intel/zoedepth-nyu-kitti), or --maps provided to use the "
                         "archive's own depth maps")
    if opts.maps == "provided" and opts.depth_model is not None:
        raise UsageError("--depth-model replaces the depth map of --maps paper or estimated; --maps provided "
                         "uses the archive's depth maps")
    if opts.limit is not None and opts.limit < 1:
        raise UsageError(f"--limit must be >= 1, got {opts.limit}")
    if opts.out.suffix.lower() not in (".yaml", ".yml"):
        raise UsageError(f"--out {opts.out}: a manifest file name ending in .yaml")
    if opts.out.is_dir():
        raise UsageError(f"--out {opts.out} is a folder; give the manifest file to write (e.g. {opts.out}/jobs.yaml)")
    blocking = next((a for a in opts.out.absolute().parents if a.exists() and not a.is_dir()), None)
    if blocking is not None:
        raise UsageError(f"--out {printable(opts.out)}: {printable(blocking)} is a file, not a folder")
    for what, path in (("--out", opts.out), ("--depth-model", opts.depth_model)):
        if not _is_utf8(path):  # the manifest is UTF-8 text and records these paths
            raise UsageError(f"{what} {printable(path)}: the path is not valid UTF-8; the manifest could not "
                             "name it")
    data = data_dir_for(opts.out)
    if data.exists() and not data.is_dir() and not opts.overwrite:
        raise UsageError(f"{printable(data)} is a file where the import writes its data folder; give --overwrite "
                         "to replace it")
    if not opts.overwrite:
        existing = [p for p in (opts.out, data) if p.exists()]
        if existing:
            raise UsageError(f"{' and '.join(map(str, existing))} already exist{'s' if len(existing) == 1 else ''}; "
                             "give --overwrite to replace them")
    if not archive.has_lights and opts.lights != "gt":
        raise UsageError("--lights applies to zcomp import spotlight")
    src = opts.src.resolve()
    if data.resolve() == src or data.resolve() in src.parents:
        raise UsageError(f"--out {opts.out} would replace the archive itself ({data})")


def select_cases(cases: list[CaseFiles], pattern: str | None, limit: int | None) -> list[CaseFiles]:
    """``--cases GLOB`` (on case names), then the first ``--limit N`` (in name order)."""
    if pattern:
        cases = [c for c in cases if fnmatch.fnmatchcase(c.name, pattern)]
    return cases[:limit] if limit else cases


def safe_name(name: str, taken: set[str]) -> str:
    """A zcomp name for a case name (the original is kept in ``case.json``): letters,
    digits, ``_ . -``, at most 100 characters, unique in ``taken`` (which it joins), and
    one the manifest takes for a job: a name that reads as a ``--jobs`` index (``7``) or
    is a file zcomp writes (``summary.json``) gets a ``case_`` prefix."""
    from zcomp_cli.limits import MAX_NAME_LEN
    from zcomp_cli.pipeline.manifest import job_name_problem

    base = _NAME_BAD.sub("_", name).lstrip(".") or "case"
    if job_name_problem(base) is not None:
        base = f"case_{base}"
    base = base[:MAX_NAME_LEN - 6]
    out, k = base, 1
    while out in taken or job_name_problem(out) is not None:
        k += 1
        out = f"{base}-{k}"
    taken.add(out)
    return out


def run_import(archive: Archive, opts: ImportOptions, progress=None, warn=None) -> ImportResult:
    """Import the selected cases of ``opts.src``; write the manifest when at least one
    case was imported (and validate it). Raises UsageError before writing anything for
    bad options or a tree with no case, InputError when no case could be imported.

    Each case is converted, then checked by its own manifest entry; a case that fails
    anywhere (an unreadable file, a light file nested 100 000 deep, a 1x1 photo, a name
    zcomp reserves...) is listed in ``failed`` with the reason and the others go on.
    ``warn(text)`` receives warnings as soon as they are known (the manifest's size)."""
    from zcomp_cli.imageio import write_json_atomic

    check_options(archive, opts)
    root = case_root(opts.src).resolve()
    estimates = shadows = None
    if archive.has_lights:
        estimates = spotlight_sibling(root, opts.estimates, SPOTLIGHT_ESTIMATES)
        shadows = spotlight_sibling(root, opts.shadows, SPOTLIGHT_SHADOWS)
        if estimates is None and opts.maps != "estimated":
            raise UsageError(f"no {SPOTLIGHT_ESTIMATES} folder found beside {root}: give --estimates DIR "
                             "(the background maps SpotLight ships), or --maps estimated")
    all_cases = list_cases(root, maps_dir=estimates, light=archive.has_lights, shadows_dir=shadows)
    cases = select_cases(all_cases, opts.cases, opts.limit)
    if not cases:
        raise UsageError(f"no case of {root} matches --cases {opts.cases!r} ({len(all_cases)} cases there)"
                         if opts.cases else f"no case found under {root}")

    out = opts.out.resolve()
    data = data_dir_for(out)
    # The cases are written to <partial>/<data name>/<case>/, laid out as they will be
    # beside the manifest: each case's own manifest is checked in <partial> before the
    # case is kept, so one bad case never sinks the others at the final check.
    partial = out.parent / f".{data.name}.partial"
    stage = partial / data.name
    made_parent = not out.parent.exists()
    out.parent.mkdir(parents=True, exist_ok=True)
    lock = _take_import_lock(out)
    result = ImportResult(None, data, root)
    entries = []
    taken: set[str] = set()  # every scene, object and job name of the manifest
    budget = _ManifestBudget(archive, opts, root, len(cases), warn)
    try:
        shutil.rmtree(partial, ignore_errors=True)  # a previous run's leftovers (interrupted)
        stage.mkdir(parents=True)
        for i, files in enumerate(cases):
            if progress is not None:
                progress(i, len(cases), files.name)
            if budget.full:  # the manifest is full: the rest are listed, not converted
                result.failed[files.name] = budget.full
                continue
            name = safe_name(files.name, taken)
            try:
                if files.problem:
                    raise InputError(files.problem)
                _check_paths(files)
                entry = _import_case(archive, opts, files, name, stage / name, data.name, taken)
                _check_case(archive, opts, root, entry, partial)
                budget.add(entry)
                entries.append(entry)
                result.imported.append(files.name)
            except Exception as exc:  # noqa: BLE001 -- one case's failure, whatever it is, is that case's
                result.failed[files.name] = _reason(exc)
                shutil.rmtree(stage / name, ignore_errors=True)
        if progress is not None:
            progress(len(cases), len(cases), "")
        if not entries:
            raise InputError(f"no case of {printable(root)} could be imported:\n  "
                             + "\n  ".join(f"{printable(k)}: {v}" for k, v in result.failed.items()))
        manifest_text = _manifest_text(archive, opts, root, entries)
        result.jobs = sum(len(e["jobs"]) for e in entries)
        write_json_atomic(stage / IMPORT_FILE, _import_report(archive, opts, root, result))
        _install(stage, data, out, manifest_text)
    finally:
        shutil.rmtree(partial, ignore_errors=True)
        lock.release()
        if made_parent and not out.exists() and not any(out.parent.iterdir()):
            out.parent.rmdir()  # nothing imported: leave no empty folder behind
    result.manifest = out
    return result


def _take_import_lock(out: Path):
    """One import at a time into one manifest (two at once shared the partial folder:
    both failed, one with a traceback). The lock file beside the manifest is flock'ed
    (released by the kernel if the process dies) and removed when the import ends."""
    from zcomp_cli.pipeline.outguard import _FileLock

    lock = _FileLock(out.parent / f".{out.name}.import.lock", {"pid": os.getpid(), "what": "zcomp import"})
    holder = lock.try_acquire()
    if holder is not None:
        pid = holder.get("pid")
        raise UsageError(f"another zcomp import{f' (pid {pid})' if pid else ''} is writing {printable(out)} now: "
                         "wait for it to end, or import into another manifest")
    return lock


def _remove(path: Path) -> None:
    """Remove a file or a folder (whichever is there)."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def _check_paths(files: CaseFiles) -> None:
    """InputError when a file of the case is not a regular file (a FIFO would hang the
    reader) or has a path that is not valid UTF-8 (a Latin-1 folder name: OpenImageIO
    takes paths as UTF-8 text and cannot open it)."""
    from zcomp_cli.pipeline.manifest import special_file_problem

    for p in (files.bundle, *files.maps.values(), files.light):
        if p is None:
            continue
        special = special_file_problem(p)
        if special:
            raise InputError(printable(special))
        if not _is_utf8(p):
            raise InputError("the path is not valid UTF-8 (a name in another encoding, e.g. Latin-1): the image "
                             "library cannot open it; rename the folder or file", where=printable(p))


def _is_utf8(path) -> bool:
    """Whether ``path`` is text UTF-8 can write (a non-UTF-8 file name decodes to
    surrogate escapes, which it cannot)."""
    try:
        str(path).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _size(n: float) -> str:
    return f"{n / 2**20:.1f} MiB" if n >= 2**20 else f"{int(n):,} bytes"


def _reason(exc: Exception) -> str:
    """One line saying why a case failed: zcomp's own errors as they are, others with
    their type (a RecursionError, an OverflowError...), bounded."""
    if isinstance(exc, ZcompError):
        return printable(str(exc))
    return printable(f"{type(exc).__name__}: {exc}")[:500]


def _check_case(archive: Archive, opts: ImportOptions, root: Path, entry: dict, partial: Path) -> None:
    """The case's own manifest (the import's defaults, its scenes, object and jobs),
    validated as ``zcomp composite`` will (files read): InputError with its problems.
    Catches what only the manifest sees (a 1x1 photo, a lamp at 1e308...) per case."""
    from zcomp_cli.imageio import write_text_atomic
    from zcomp_cli.pipeline.manifest import load_manifest

    check = partial / "case-check.yaml"
    write_text_atomic(check, _manifest_text(archive, opts, root, [entry]))
    try:
        load_manifest(check)
    except ManifestError as exc:
        shown = [re.sub(rf"^{re.escape(check.name)}(:\d+)?: ", "", p) for p in exc.problems[:5]]
        raise InputError("the case's manifest entry does not validate: " + "; ".join(shown)
                         + (f" (and {len(exc.problems) - 5} more)" if len(exc.problems) > 5 else "")) from None
    finally:
        check.unlink(missing_ok=True)


class _ManifestBudget:
    """The written manifest must load (``ZCOMP_MAX_MANIFEST_BYTES``, 4 MiB by default):
    cases are kept while their YAML fits; the cases past it are listed as failed
    without being converted. After the first case the whole selection's size is
    estimated and a warning given up front when it will not fit."""

    def __init__(self, archive: Archive, opts: ImportOptions, root: Path, n_cases: int, warn=None):
        from zcomp_cli.limits import max_manifest_bytes

        self.limit = max_manifest_bytes()
        self.used = len(_manifest_text(archive, opts, root, []).encode()) + 64  # the head (its case count), defaults
        self.n_cases, self.kept, self.warn = n_cases, 0, warn
        self.full: str | None = None

    def add(self, entry: dict) -> None:
        """Count ``entry`` in, or raise InputError (and mark the budget full) when it
        does not fit."""
        import yaml

        # the case's sections alone: their keys counted again for every case, so the sum
        # stays above the manifest written (which must load under the same limit)
        size = len(yaml.safe_dump({k: entry[k] for k in ("scenes", "objects", "jobs")}, sort_keys=False,
                                   width=120).encode())
        if self.used + size > self.limit:
            from zcomp_cli.limits import MAX_MANIFEST_BYTES_ENV

            self.full = (f"not imported: the manifest would pass its size limit of {self.limit:,} bytes after "
                         f"{self.kept} case{'s' * (self.kept != 1)} (set ${MAX_MANIFEST_BYTES_ENV} for this "
                         "import and for the runs that read it, or import in parts with --cases/--limit)")
            raise InputError(self.full)
        self.used += size
        self.kept += 1
        if self.kept == 1 and self.warn is not None and self.used + size * (self.n_cases - 1) > self.limit:
            from zcomp_cli.limits import MAX_MANIFEST_BYTES_ENV

            fit = max(1, int((self.limit - self.used) // size) + 1)
            self.warn(f"{self.n_cases} cases make a manifest of about {_size(self.used + size * (self.n_cases - 1))}"
                      f", past its limit of {_size(self.limit)}: about {fit} will be imported, the "
                      f"rest listed as not imported (set ${MAX_MANIFEST_BYTES_ENV}, or import in parts with "
                      "--cases/--limit)")


def _install(partial: Path, data: Path, out: Path, manifest_text: str) -> None:
    """Move the new data folder into place, write the manifest beside it and validate
    it; on a validation failure the previous import (if any) is put back."""
    from zcomp_cli.pipeline.manifest import load_manifest

    old = data.parent / f".{data.name}.old-{os.getpid()}"
    had_old = data.exists()
    if had_old:
        os.replace(data, old)
    os.replace(partial, data)
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}{out.suffix}"
    try:
        tmp.write_text(manifest_text)
        try:
            load_manifest(tmp)  # "a manifest that zcomp composite runs as it is"
        except ManifestError as exc:  # a bug of the importer: say so, in the final file's name
            raise ManifestError([f"the manifest zcomp import made does not validate (nothing was kept): "
                                 f"{p.replace(tmp.name, out.name)}" for p in exc.problems], source=str(out)) from exc
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        _remove(data)
        if had_old:
            os.replace(old, data)
        raise
    if had_old:
        _remove(old)  # a file where the data folder was, too (rmtree left it as .old-<pid>)


# ----------------------------------------------------------------------------- one case
def _import_case(archive: Archive, opts: ImportOptions, files: CaseFiles, name: str, case_dir: Path,
                 data_name: str, taken: set[str]) -> dict:
    """Convert one case into ``case_dir``; return its scene, object and job entries
    (their names unique in ``taken``, the names of the whole manifest)."""
    from zcomp_cli.imageio import write_exr, write_json_atomic, write_png

    bc = read_bundle(files.bundle, archive.reading, normals_frame=opts.bundle_normals)
    cam = bc.bundle.camera
    case_dir.mkdir(parents=True)
    rel = f"{data_name}/{name}"
    conversions = [
        f"bundle layers read as {archive.reading.loader} reads them: value channel {archive.reading.value_channel}"
        + (", divided by the layer's alpha (premultiplied)" if bc.checks["value_layers_premultiplied"] else ""),
        f"bundle normals: frame {bc.checks['normals_frame']!r}"
        + (" (z negated: Blender shader camera space -> zcomp camera frame)"
           if bc.checks["normals_frame"] == "blender-camera" else " (kept: already zcomp's camera frame)"),
        "background, composite: linear, kept linear (the official loaders gamma-encode them for the model)",
    ]
    write_exr(case_dir / "background.exr", bc.background)
    write_exr(case_dir / "reference.exr", bc.reference)
    write_png(case_dir / "object_mask.png", bc.bundle.mask, srgb_encode=False, bits=16)
    bc.bundle.save(case_dir / "object")

    scene = {"image": f"{rel}/background.exr", "fov_deg": lvsn.FOV_DEG}
    checks = dict(bc.checks)
    bg_depth = None
    map_files = _wanted_maps(opts.maps)
    for m in map_files:
        src = files.maps.get(m)
        if src is None:
            if m in ("roughness", "metallic"):
                continue
            looked = (files.folder if archive.key == "zerocomp" else (opts.estimates or "the estimates folder"))
            raise InputError(f"no {m} map: {files.name}{BG_MAP_SUFFIX[m]} not found in {looked} "
                             f"(needed by --maps {opts.maps})")
        arr, note = _read_bg_map(m, src, cam)
        if m == "depth":
            bg_depth = arr
        if note:
            conversions.append(note)
        if m == "normals":
            checks["background_normals_facing_fraction"] = lvsn.facing_fraction(arr, cam.K)
        write_exr(case_dir / f"{m}.exr", arr)
        scene[m] = f"{rel}/{m}.exr"
    if opts.maps in ("paper", "estimated"):
        scene["depth"] = {"model": str(Path(opts.depth_model).resolve())}
        conversions.append("depth: estimated at composite time by the depth model (the paper: ZoeDepth NK)")

    from zcomp_cli.datasets.lights import GT_FRAME, lamp_entry, read_light_frames, select_frames

    light_info = None
    scenes, jobs = {}, []
    frames = []
    if archive.has_lights and opts.lights != "none":
        if files.light is None:
            raise InputError(f"no light path: {files.name}_light_path_dto.json not found in {files.folder} "
                             "(--lights none imports the case without its light)")
        frames = select_frames(read_light_frames(files.light), opts.lights, str(files.light))
        light_info = _light_info(bc, bg_depth)
    if not frames:
        scenes[name] = scene
        jobs.append(_job(name, name, name, bc, f"{rel}/reference.exr"))
    for fr in frames:
        sname = name if opts.lights == "gt" else safe_name(f"{name}_light{fr.name}", taken)
        lamp = lamp_entry(fr, light_info["centre_used"])
        scenes[sname] = {**scene, "light": [lamp]}
        light_info.setdefault("lamps", {})[fr.name] = lamp
        ref = f"{rel}/reference.exr" if fr.name == GT_FRAME else None
        jobs.append(_job(sname, name, sname, bc, ref))
    info = {
        "dataset": archive.reading.dataset, "archive": archive.title, "case": printable(files.name), "name": name,
        "bundle": printable(files.bundle), "maps": {k: printable(v) for k, v in files.maps.items()},
        "maps_used": opts.maps, "light_path": printable(files.light) if files.light else None,
        "shadows": [printable(p) for p in files.shadows], "size": [cam.width, cam.height],
        "conversions": conversions, "checks": checks, "notes": bc.notes, "light": light_info,
    }
    if cam.width != cam.height:
        info["notes"].append(f"{cam.width}x{cam.height} is not square: the paper scored the centre "
                             "short-side square (its Resize + CenterCrop); zcomp scores the whole frame")
    write_json_atomic(case_dir / CASE_FILE, _jsonable(info))
    return {"scenes": scenes, "objects": {name: {"bundle": f"{rel}/object"}}, "jobs": jobs, "info": info}


def _wanted_maps(maps: str) -> tuple[str, ...]:
    if maps == "provided":
        return ("depth", "normals", "albedo", "roughness", "metallic")
    if maps == "paper":
        return ("normals", "albedo", "roughness", "metallic")
    return ()


def _read_bg_map(m: str, path: Path, cam) -> tuple[np.ndarray, str]:
    """One archive background map in zcomp's conventions (and a line saying how)."""
    from zcomp_cli.imageio import read_map

    arr = read_map(path, channels=3 if m in ("normals", "albedo") else 1)
    if arr.shape[:2] != (cam.height, cam.width):
        raise InputError(f"the map is {arr.shape[1]}x{arr.shape[0]}, the bundle {cam.width}x{cam.height}",
                         where=str(path))
    if not np.isfinite(arr).any():
        # (made 0 below, an all-NaN normals map became one constant normal everywhere)
        raise InputError(f"the {m} map holds no finite value (every pixel NaN or infinite)", where=str(path))
    arr = np.nan_to_num(arr.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    if m == "depth":
        from zcomp_cli.conventions import blender_depth_to_z_depth

        return blender_depth_to_z_depth(arr), f"{path.name}: channel 0, z-depth in metres (<= 0 -> invalid)"
    if m == "normals":
        n = lvsn.stablenormal_png_to_camera_normals(arr)
        facing = lvsn.facing_fraction(n, cam.K)
        if not np.isfinite(facing):
            raise InputError("the normals map holds no usable normal (every pixel zero once read)", where=str(path))
        if not facing >= lvsn.MIN_FACING_FRACTION:
            raise InputError(f"the normals face away from the camera at {1 - facing:.0%} of the pixels once "
                             "read as StableNormal's (x negated): not a StableNormal map?", where=str(path))
        return n, f"{path.name}: StableNormal, 2 e - 1 with x negated -> zcomp camera frame"
    what = "linear albedo" if m == "albedo" else m
    return np.clip(arr, 0.0, 1.0), f"{path.name}: values / 255 taken as {what} (no sRGB or gamma decoding)"


def _light_info(bc, bg_depth) -> dict:
    """Where the lamps are placed: around the object's centre, moved with zcomp's
    footprint alignment when the background depth is known now (a provided map)."""
    from zcomp_cli.compositing.alignment import align_depth
    from zcomp_cli.datasets.lights import aligned_centre

    info = {"centre_bundle": bc.centre.tolist(), "base_bundle": bc.base.tolist(),
            "distance_m": lvsn.SPOTLIGHT_LIGHT_DISTANCE_M, "radius_m": lvsn.SPOTLIGHT_LIGHT_RADIUS_M}
    if bg_depth is not None:
        al = align_depth(bg_depth, bc.bundle.footprint_depth)
        info["alignment"] = al.to_dict()
        info["centre_used"] = aligned_centre(bc.centre, al).tolist()
        info["centre_note"] = "the object's centre moved with zcomp's footprint alignment to the provided depth"
    else:
        info["centre_used"] = bc.centre.tolist()
        info["centre_note"] = ("the object's centre in the bundle's frame: the depth is estimated at composite "
                               "time, so zcomp's alignment may move the object along its ray while the lamp stays")
    return info


def _job(scene: str, obj: str, output: str, bc, reference: str | None) -> dict:
    job = {"scene": scene, "object": obj, "output": output,
           "pose": {"position": [round(float(x), 6) for x in bc.base]}}
    if reference:
        job["reference"] = reference
    return job


def _jsonable(o):
    if isinstance(o, dict):
        return {k: _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return o


# ----------------------------------------------------------------------------- manifest
def _manifest_text(archive: Archive, opts: ImportOptions, root: Path, entries: list[dict]) -> str:
    import yaml

    doc = {
        "version": 1,
        "defaults": {
            "renderer": {"name": "zerocomp", "window": lvsn.PAPER_WINDOW, "steps": lvsn.PAPER_STEPS,
                         "dtype": lvsn.PAPER_DTYPE},
            "seed": lvsn.PAPER_SEED,
            "shading_radius": archive.shading_radius,
        },
        "scenes": {k: v for e in entries for k, v in e["scenes"].items()},
        "objects": {k: v for e in entries for k, v in e["objects"].items()},
        "jobs": [j for e in entries for j in e["jobs"]],
    }
    maps_line = {
        "paper": "depth from the depth model on each photo, normals and albedo from the archive's precomputed maps",
        "provided": "the archive's precomputed depth, normals and albedo",
        "estimated": "depth from the depth model, normals from the depth, albedo by Retinex (zcomp's estimators)",
    }[opts.maps]
    head = [
        f"# zcomp import {archive.key}: {len(entries)} case{'s' * (len(entries) != 1)} of the {archive.title} "
        f"({printable(root)})",  # one comment line whatever the path holds (a newline, non-UTF-8 bytes)
        f"# maps: {opts.maps} ({maps_line})",
        f"# The paper's settings: centre crop (window: center), fov {lvsn.FOV_DEG:g}, seed {lvsn.PAPER_SEED},",
        f"# {lvsn.PAPER_STEPS} DDIM steps, fp16 under autocast, shading mask radius {archive.shading_radius:g}.",
        "# Run: zcomp composite THIS --out OUT [--renderer physical|naive]; zcomp eval OUT",
        "# Per-case conversions and checks: <data>/<case>/case.json (docs/reproduce.md).",
    ]
    return "\n".join(head) + "\n" + yaml.safe_dump(doc, sort_keys=False, width=120)


def _import_report(archive: Archive, opts: ImportOptions, root: Path, result: ImportResult) -> dict:
    from zcomp_cli import __version__

    return {
        "zcomp": __version__, "dataset": archive.reading.dataset, "archive": archive.title, "root": str(root),
        "maps": opts.maps, "depth_model": str(opts.depth_model) if opts.depth_model else None,
        "cases_filter": opts.cases, "limit": opts.limit, "lights": opts.lights if archive.has_lights else None,
        "imported": result.imported, "failed": result.failed, "jobs": result.jobs,
    }

