"""What a batch leaves in its output folder, and how a re-run reads it back.

Per job, ``OUT/<job name>/``: ``composite.png`` (sRGB 8-bit), ``composite.exr``
(linear), ``report.json`` (written last: its presence with ``status: done`` marks a
finished job), with ``--debug`` the intermediate maps and ``grid.png`` (and the
renderer's own maps, ``RenderOutput.debug_maps``, beside them in ``debug/`` with their
sheet ``light_evidence.png``), with ``--aovs`` ``aovs.exr`` (the render passes as
layers). The batch
ends with ``OUT/summary.json``. Every file is written atomically (``imageio``).

``report.json`` records the size and sha256 of every file of the job (``outputs``);
``--resume`` skips a job only when they all still match and its inputs' fingerprint is
unchanged. The fingerprint hashes input *contents* (paths relative to the manifest), so
``touch`` or moving the project does not invalidate finished jobs.

``summary.json`` is the merged state of the output folder for the manifest's jobs:
``done`` (finished, in this run or an earlier one), ``failed`` (the latest attempt
failed) or ``pending`` (not finished); it is rewritten, under a lock, when a run starts
and when it ends, so a killed run never leaves a summary claiming more than is there.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import logging

import numpy as np

from zcomp_cli import __version__
from zcomp_cli.errors import UsageError
from zcomp_cli.limits import field_text
from zcomp_cli.safe_read import JsonFileError, read_json_file
from zcomp_cli.pipeline.fingerprint import job_fingerprint  # noqa: F401 - re-exported
from zcomp_cli.pipeline.manifest import JobSpec, Manifest, RendererSpec

REPORT = "report.json"
SUMMARY = "summary.json"
AOVS = "aovs.exr"  # --aovs: the render passes, one multi-layer EXR (compositing.aovs)
log = logging.getLogger(__name__)
DEBUG_MAPS = ("f_bg", "f_comp", "ratio", "ratio_blurred", "shading_mask", "object_mask", "weight",
              "comp_depth", "comp_normals", "comp_albedo", "shading")
# --debug: the renderer's own debug maps (``RenderOutput.debug_maps``; the physical
# renderer's light evidence) beside the background, one sheet
MAPS_SHEET = "light_evidence.png"
# A renderer's debug map name: a file name's stem, no path (lower case: two names never
# meet in one file on a case-insensitive file system).
DEBUG_MAP_NAME = re.compile(r"[a-z0-9][a-z0-9_-]{0,63}")


@dataclass
class JobStatus:
    job: JobSpec
    status: str  # "done" | "skipped" | "failed"
    reason: str | None = None
    seconds: float = 0.0
    out_dir: Path | None = None


@dataclass
class BatchSummary:
    statuses: list[JobStatus] = field(default_factory=list)
    seconds: float = 0.0
    blender: dict = field(default_factory=dict)
    # --shard: {"index": i, "count": n, "jobs": [names of the shard's jobs]}
    shard: dict | None = None
    executor: dict = field(default_factory=dict)

    def count(self, status: str) -> int:
        return sum(1 for s in self.statuses if s.status == status)

    @property
    def ok(self) -> bool:
        return self.count("failed") == 0

    def to_dict(self) -> dict:
        return {
            "done": self.count("done"), "skipped": self.count("skipped"), "failed": self.count("failed"),
            "seconds": self.seconds, "blender": self.blender, "shard": self.shard,
            "executor": self.executor,
            "jobs": [{"index": s.job.index, "name": s.job.name, "status": s.status, "reason": s.reason,
                      "seconds": s.seconds} for s in self.statuses],
        }


def read_report(out_dir: Path) -> dict | None:
    """A job folder's ``report.json`` as a mapping, or None when there is none or it is
    damaged (not JSON, or JSON that is not a mapping: ``[]``, ``"done"``, ``3``)."""
    return read_report_noted(out_dir)[0]


def read_report_noted(out_dir: Path) -> tuple[dict | None, str | None]:
    """(report, note): the note says why an existing ``report.json`` was not usable."""
    p = Path(out_dir) / REPORT
    try:
        if not os.path.lexists(p):
            return None, None
        doc = read_json_file(p)
    except JsonFileError as exc:
        return None, f"{p}: {exc}; treated as missing"
    except (OSError, ValueError) as exc:
        return None, f"{p}: unreadable ({type(exc).__name__}), treated as missing"
    if not isinstance(doc, dict):
        return None, f"{p}: holds {type(doc).__name__}, not a job report; treated as missing"
    return doc, None


# What zcomp writes in a job folder (and its debug/ folder): a folder holding anything
# else is not a job folder, and a run refuses to write into it.
JOB_FILES = {REPORT, "composite.png", "composite.exr", AOVS, "grid.png", "shading_mask.png", MAPS_SHEET, "debug"}
DEBUG_FILES = {f"{n}.exr" for n in DEBUG_MAPS}


def renderer_debug_files() -> set[str]:
    """``<name>.exr`` of every debug map a known renderer declares
    (``RendererEntry.debug_maps``, plugins included)."""
    from zcomp_cli.renderers.registry import RENDERERS

    return {f"{n}.exr" for e in RENDERERS.values() for n in getattr(e, "debug_maps", ())
            if isinstance(n, str) and DEBUG_MAP_NAME.fullmatch(n)}


def _recorded_debug_files(job_dir: Path) -> set[str]:
    """The ``debug/`` files the job's report records as its outputs (a renderer's maps
    that no registry entry declares)."""
    rep = read_report(job_dir)
    outs = rep.get("outputs") if rep is not None else None
    if not isinstance(outs, dict):
        return set()
    return {k[len("debug/"):] for k in outs if isinstance(k, str) and k.startswith("debug/")
            and "/" not in k[len("debug/"):] and k.endswith(".exr")}


def foreign_entries(job_dir: Path) -> list[str]:
    """Entries of ``job_dir`` that zcomp did not write (hidden temporaries count as
    zcomp's; in ``debug/``, the pipeline's maps, those the renderers declare and those
    the job's report records). Empty for a job folder, or one that does not exist."""
    def theirs(folder: Path, ours: set[str]) -> list[str]:
        try:
            names = sorted(os.listdir(folder))
        except (FileNotFoundError, NotADirectoryError):
            return []
        return [n for n in names if n not in ours and not (n.startswith(".") and ".tmp" in n)]

    found = theirs(job_dir, JOB_FILES)
    debug = job_dir / "debug"
    if debug.is_dir() and not debug.is_symlink():
        extra = theirs(debug, DEBUG_FILES)
        if extra:  # (the registry and the report only when needed)
            extra = theirs(debug, DEBUG_FILES | renderer_debug_files() | _recorded_debug_files(job_dir))
        found += [f"debug/{n}" for n in extra]
    elif debug.exists() or debug.is_symlink():
        found.append("debug")
    return found


@dataclass
class JobState:
    """What a job folder holds, as ``--resume`` and ``zcomp status`` judge it:

    * ``done``: a report that says done, every output it records intact, made from the
      expected inputs (when a fingerprint is given);
    * ``stale``: done, but made from other inputs or settings;
    * ``damaged``: a done report whose outputs are missing, empty or altered;
    * ``incomplete``: done, but without what this run asks for (``--debug`` maps);
    * ``unfinished``: no usable report (never made, interrupted, or a damaged report).
    """

    state: str
    reason: str | None = None
    report: dict | None = None
    note: str | None = None  # why an existing report.json was not usable


def job_state(job_dir: Path, fingerprint: str | None = None, *, need_debug: bool = False,
              need_aovs: bool = False, verify: bool = True) -> JobState:
    """Judge ``job_dir`` (see ``JobState``). ``verify`` False checks output sizes only
    (no hashing)."""
    from zcomp_cli.pipeline.outguard import verify_outputs

    if os.path.islink(job_dir):  # composite refuses it: never done, whatever it leads to
        return JobState("damaged", "the job folder is a symbolic link (zcomp writes only inside the output "
                                   "folder; `zcomp composite` refuses it): remove the link", None)
    rep, note = read_report_noted(job_dir)
    if rep is None or rep.get("status") != "done":
        return JobState("unfinished", note or ("no report.json" if rep is None else "its report is not done"),
                        rep, note)
    why = verify_outputs(job_dir, rep.get("outputs")) if verify else (
        None if _sizes_match(job_dir, rep) else "an output is missing or has another size")
    if why is not None:
        return JobState("damaged", why, rep)
    if need_debug and not any(str(k).startswith("debug/") for k in rep["outputs"]):
        return JobState("incomplete", "made without --debug: no debug maps", rep)
    if need_aovs and AOVS not in rep["outputs"]:
        return JobState("incomplete", f"made without --aovs: no {AOVS}", rep)
    if fingerprint is not None and rep.get("fingerprint") != fingerprint:
        return JobState("stale", "made from other inputs or settings", rep)
    return JobState("done", None, rep)


def plan_outputs(manifest, jobs, out_root: Path, renderer, samples, *, resume: bool, overwrite: bool,
                 redo_changed: bool = False, debug: bool = False, aovs: bool = False, digests=None):
    """Decide, before any work, which jobs run and which are skipped.

    A job counts as finished only when its report says ``done`` and every output it
    records is still there with its size and hash (``job_state``); with ``debug`` it
    must also hold its debug maps. A job folder that is a symbolic link (or leads
    outside ``out_root``), or that holds files zcomp did not write, is refused. With
    ``resume``, finished jobs of the same inputs are skipped; ``redo_changed`` redoes
    those made from other inputs (else they are refused: nothing is replaced unasked).
    Returns (to_run as ``[(job, fingerprint)]``, skipped statuses). Raises UsageError
    when finished outputs exist and the flags do not say what to do with them."""
    from zcomp_cli.pipeline.outguard import check_inside

    to_run, skipped, clashes, changed, foreign = [], [], [], [], []
    for job in jobs:
        out_dir = out_root / job.name
        field = f"jobs[{job.index}].output ({job.name})"
        check_inside(out_root, out_dir, field)
        if out_dir.is_dir():
            check_inside(out_root, out_dir / "debug", field)
        elif out_dir.exists():
            foreign.append(f"{field}: {out_dir} exists and is not a folder")
            continue
        theirs = foreign_entries(out_dir)
        if theirs:
            foreign.append(f"{field}: {out_dir} is not a zcomp job folder (it holds "
                           f"{', '.join(theirs[:4])}{' ...' if len(theirs) > 4 else ''})")
            continue
        fp = job_fingerprint(manifest, job, renderer, samples, digests)
        st = job_state(out_dir, fp, need_debug=debug, need_aovs=aovs)
        if st.note:
            log.warning("%s", st.note)
        if st.state in ("unfinished", "damaged") or overwrite:
            to_run.append((job, fp))
        elif st.state == "incomplete" and resume:  # --resume --debug/--aovs: make what is missing
            to_run.append((job, fp))
        elif st.state == "done" and resume:
            skipped.append(JobStatus(job, "skipped", "finished in an earlier run (--resume)", 0.0, out_dir))
        elif st.state == "stale" and resume and redo_changed:
            to_run.append((job, fp))
        elif resume:
            changed.append(job.name)
        else:
            clashes.append(job.name)

    def shown(names):
        return ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")

    if foreign:
        raise UsageError(f"{len(foreign)} job output(s) would be written into something that is not a zcomp job "
                         f"folder (nothing was written):\n  " + "\n  ".join(foreign[:10])
                         + ("\n  ..." if len(foreign) > 10 else "")
                         + "\nname another 'output' for these jobs, or use another --out")
    if changed:
        raise UsageError(
            f"{len(changed)} finished job(s) in {out_root} were made from other inputs or settings: "
            f"{shown(changed)}. Add --redo-changed to redo exactly these (the unchanged ones are "
            "skipped), use --overwrite to redo every job, or use another --out.")
    if clashes:
        raise UsageError(
            f"{len(clashes)} job output(s) already exist in {out_root}: {shown(clashes)}. "
            "Pass --resume to skip finished jobs or --overwrite to replace them.")
    return to_run, skipped


def job_report(manifest: Manifest, job: JobSpec, fingerprint: str, scene, pose, bundle_dir, result, *,
               renderer_spec: RendererSpec | None = None) -> dict:
    """The ``report.json`` body of a finished job (timings are completed by the writer).
    ``renderer_spec`` (what the run was asked for, with command-line overrides) lets
    ``zcomp status --manifest`` recompute the fingerprint the job was made with."""
    return {
        "status": "done",
        "zcomp_version": __version__,
        "fingerprint": fingerprint,
        "renderer_spec": None if renderer_spec is None else {"name": renderer_spec.name,
                                                             "settings": dict(renderer_spec.settings)},
        "job": {"index": job.index, "name": job.name, "scene": job.scene, "object": job.object,
                "manifest": str(manifest.path), "line": job.line},
        "pose": None if pose is None else pose.to_dict(),
        "placement": None if job.placement is None else vars(job.placement),
        "reference": None if job.reference is None else str(job.reference),
        "scene": {"key": scene.key, "size": [scene.camera.width, scene.camera.height],
                  "K": scene.camera.K.tolist(), "sources": scene.sources, "timings": scene.timings},
        **result.report,
        "object_bundle": None if bundle_dir is None else str(bundle_dir),
    }


def write_job_outputs(out_dir: Path, scene, result, report: dict, *, debug: bool, aovs: bool = False,
                      started: float | None = None) -> float:
    """Write a finished job's files, ``report.json`` last. Returns the seconds spent.
    ``started`` (a ``time.perf_counter()`` value) adds ``job_total_s`` to the report."""
    import time

    from zcomp_cli.imageio import write_exr, write_json_atomic, write_png

    out_dir.mkdir(parents=True, exist_ok=True)
    # A stale report must not vouch for new files while they are being written.
    stale = out_dir / REPORT
    if stale.exists():
        stale.unlink()
    t = time.perf_counter()
    write_exr(out_dir / "composite.exr", result.image)
    write_png(out_dir / "composite.png", result.image)
    if debug:
        write_debug(out_dir, scene, result)
    if aovs:
        from zcomp_cli.compositing.aovs import channel_names

        data, names = channel_names(result.aovs)
        write_exr(out_dir / AOVS, data, channel_names=names)
    t_write = time.perf_counter() - t
    from zcomp_cli.pipeline.outguard import output_record

    files = sorted(p for p in out_dir.rglob("*") if p.is_file() and p.name != REPORT
                   and not p.name.startswith("."))
    report["outputs"] = {str(p.relative_to(out_dir)): output_record(p) for p in files}
    report["timings"] = {**report.get("timings", {}), "write_s": t_write}
    if isinstance(report.get("stages"), list):  # (the job's ledger, ``pipeline.ledger``)
        report["stages"] = [*report["stages"], {"stage": "write", "status": "run", "why": None,
                                                "seconds": round(t_write, 4)}]
    if started is not None:
        report["timings"]["job_total_s"] = time.perf_counter() - started
    write_json_atomic(out_dir / REPORT, report)
    return t_write


def summary_name(shard: dict | None) -> str:
    """``summary.json``, or ``summary.shard-I-of-N.json`` for shard I (from 0) of N:
    shards running side by side in one folder never write the same file."""
    if not shard:
        return SUMMARY
    return f"summary.shard-{shard['index']}-of-{shard['count']}.json"


def write_summary(out_root: Path, summary: BatchSummary, manifest: Manifest | None = None, *,
                  running: set[str] | frozenset = frozenset()) -> dict:
    """Merge this run's statuses with the state of ``out_root`` and write the summary
    (``summary_name``; under the summary lock, so runs writing side by side never lose
    each other's jobs). Jobs in ``running`` are reported ``pending`` (being made).
    Returns the document."""
    from zcomp_cli.imageio import write_json_atomic
    from zcomp_cli.pipeline.outguard import clean_root_temporaries, summary_lock

    with summary_lock(out_root):
        clean_root_temporaries(out_root)
        doc = merged_summary(out_root, summary, manifest, running=running)
        write_json_atomic(out_root / summary_name(summary.shard), doc)
    return doc


def merged_summary(out_root: Path, summary: BatchSummary, manifest: Manifest | None, *,
                   running=frozenset()) -> dict:
    """The summary document: every job of the manifest (of the shard, for a shard) with
    its state in the folder; ``this_run`` counts what this run did (done, skipped,
    failed)."""
    prev = {}
    try:
        old = read_json_file(out_root / summary_name(summary.shard))
        prev = {j["name"]: j for j in old.get("jobs", []) if isinstance(j, dict) and isinstance(j.get("name"), str)}
    except (OSError, ValueError, AttributeError, TypeError):
        pass
    mine = {s.job.name: s for s in summary.statuses}
    jobs = list(manifest.jobs) if manifest is not None else [s.job for s in summary.statuses]
    if summary.shard:
        keep = set(summary.shard.get("jobs") or [])
        jobs = [j for j in jobs if j.name in keep]
    rows = []
    for job in jobs:
        st = mine.get(job.name)
        row = {"index": job.index, "name": job.name, "status": "pending", "reason": None, "seconds": 0.0,
               "this_run": None}
        if job.name in running:
            row["reason"] = "being made"
        elif st is not None and st.status in ("done", "failed"):
            reason = None if st.reason is None else field_text(st.reason)
            row.update(status=st.status, reason=reason, seconds=st.seconds, this_run=st.status)
        else:
            if st is not None:
                row["this_run"] = st.status
            rep = read_report(out_root / job.name)
            if rep is not None and rep.get("status") == "done" and _sizes_match(out_root / job.name, rep):
                timings = rep.get("timings") if isinstance(rep.get("timings"), dict) else {}
                secs = timings.get("job_total_s")
                row.update(status="done", reason=st.reason if st is not None else "finished in an earlier run",
                           seconds=float(secs) if isinstance(secs, (int, float)) else 0.0)
            elif prev.get(job.name, {}).get("status") == "failed":
                row.update(status="failed", reason=field_text(prev[job.name].get("reason") or "failed"))
        rows.append(row)
    count = {k: sum(1 for r in rows if r["status"] == k) for k in ("done", "failed", "pending")}
    return {
        **count,
        "skipped": summary.count("skipped"),
        "this_run": {k: summary.count(k) for k in ("done", "skipped", "failed")},
        "seconds": summary.seconds, "blender": summary.blender, "shard": summary.shard,
        "executor": summary.executor,
        "jobs": rows,
    }


def _sizes_match(job_dir: Path, rep: dict) -> bool:
    """Cheap check (sizes, no hashing) that a report's outputs are still there."""
    outs = rep.get("outputs")
    if not isinstance(outs, dict) or not outs:
        return False
    for name, rec in outs.items():
        if Path(name).is_absolute() or ".." in Path(name).parts:
            return False
        p = job_dir / name
        try:
            if not isinstance(rec, dict) or p.stat().st_size != rec.get("bytes") or rec.get("bytes") == 0:
                return False
        except OSError:
            return False
    return True


def write_debug(out_dir: Path, scene, result) -> None:
    """``--debug``: the pipeline's maps and the renderer's (``JobOutput.renderer_debug``,
    checked by ``job.check_debug_maps``) under ``debug/``, ``shading_mask.png``,
    ``grid.png`` and, when the renderer gave maps, their sheet ``MAPS_SHEET``. A
    renderer's map or sheet an earlier run left that this one did not make is removed
    (else the report would vouch for it)."""
    from zcomp_cli.imageio import write_exr, write_png

    d = result.debug
    for name in DEBUG_MAPS:
        if name in d:
            write_exr(out_dir / "debug" / f"{name}.exr", d[name])
    rmaps = dict(getattr(result, "renderer_debug", None) or {})
    for name, a in rmaps.items():
        write_exr(out_dir / "debug" / f"{name}.exr", a)
    mine = {f"{n}.exr" for n in rmaps}
    for n in sorted(renderer_debug_files() - DEBUG_FILES - mine):
        stale = out_dir / "debug" / n
        if stale.is_file() and not stale.is_symlink():
            stale.unlink()
    write_png(out_dir / "shading_mask.png", d["shading_mask"], srgb_encode=False)
    write_png(out_dir / "grid.png", debug_grid(scene.image, d["f_bg"], d["f_comp"], d["ratio_blurred"],
                                               d["shading_mask"], result.image), srgb_encode=False)
    if rmaps:
        write_png(out_dir / MAPS_SHEET, maps_sheet(scene.image, rmaps), srgb_encode=False)
    elif (out_dir / MAPS_SHEET).is_file() and not (out_dir / MAPS_SHEET).is_symlink():
        (out_dir / MAPS_SHEET).unlink()


# Where a debug map holds NaN (no value: the shadow ratio off the support), its tile
# shows this colour (sRGB).
NAN_COLOUR = (0.18, 0.24, 0.55)


def maps_sheet(x_bg, maps: dict, columns: int = 3) -> np.ndarray:
    """The renderer's debug maps beside the background (``MAPS_SHEET``): tiles of
    ``columns`` per row, the background first, then each map under its name; a
    one-channel map as grey, its values clipped to [0, 1] (not sRGB-encoded: data),
    NaN in ``NAN_COLOUR``; a colour map sRGB-encoded. Returns sRGB-encoded [0, 1]
    float (rows * H, columns * W, 3)."""
    from zcomp_cli.conventions import linear_to_srgb

    bg = np.asarray(x_bg, np.float32)
    H, W = bg.shape[:2]
    tiles = [(linear_to_srgb(np.clip(np.nan_to_num(bg), 0, None)), "background")]
    for name, a in maps.items():
        a = np.asarray(a, np.float32)
        if a.ndim == 3 and a.shape[2] == 1:
            a = a[..., 0]
        if a.ndim == 2:
            nan = np.isnan(a)
            t = np.repeat(np.clip(np.nan_to_num(a, nan=0.0), 0.0, 1.0)[..., None], 3, -1)
            t[nan] = NAN_COLOUR
            label = f"{name} (blue: none)" if nan.any() else name
        else:
            t = linear_to_srgb(np.clip(np.nan_to_num(a[..., :3]), 0, None))
            label = name
        tiles.append((t.astype(np.float32), label))
    tiles = [_labelled(t, label) for t, label in tiles]
    rows = -(-len(tiles) // columns)
    sheet = np.zeros((rows * H, columns * W, 3), np.float32)
    for i, t in enumerate(tiles):
        r, c = divmod(i, columns)
        sheet[r * H:(r + 1) * H, c * W:(c + 1) * W] = t
    return sheet


def _labelled(tile: np.ndarray, label: str) -> np.ndarray:
    """The tile with ``label`` written in its top-left corner (white on a dark outline)."""
    import cv2

    t = np.ascontiguousarray(np.clip(tile, 0.0, 1.0), dtype=np.float32)
    H, W = t.shape[:2]
    scale = max(0.35, min(1.0, W / 800.0))
    org = (max(3, W // 100), max(12, int(22 * scale)))
    for colour, thick in (((0.0, 0.0, 0.0), 3), ((1.0, 1.0, 1.0), 1)):
        cv2.putText(t, label, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)
    return t


def debug_grid(x_bg, f_bg, f_comp, ratio, mask, result) -> np.ndarray:
    """2 x 3 sheet like the paper's Figure 3, each panel named in its corner
    (``GRID_LABELS``): background, f(i_bg), f(i_comp) / R', shading mask, result.
    Returns sRGB-encoded [0, 1] float (H*2, W*3, 3)."""
    from zcomp_cli.conventions import linear_to_srgb

    def col(a):
        a = np.asarray(a, dtype=np.float32)
        return np.repeat(a[..., None], 3, -1) if a.ndim == 2 else a

    tiles = [linear_to_srgb(col(x)) for x in (x_bg, f_bg, f_comp)]
    tiles += [np.clip(col(ratio), 0, 1), np.clip(col(mask), 0, 1), linear_to_srgb(col(result))]
    tiles = [_labelled(t, label) for t, label in zip(tiles, GRID_LABELS)]
    return np.concatenate([np.concatenate(tiles[:3], 1), np.concatenate(tiles[3:], 1)], 0)


# grid.png's panels, in order (top row, then bottom row)
GRID_LABELS = ("background", "render of the background f(i_bg)", "render with the object f(i_comp)",
               "shadow ratio R'", "shading mask", "result")
