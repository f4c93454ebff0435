"""The rows of ``zcomp report``: one plain dict per job of an output folder.

Reads only. The jobs and their status (done, failed with the reason, missing, damaged)
come from ``pipeline.status.folder_status``, the way ``zcomp status`` merges runs and
shards; the rest from each job's ``report.json`` (scene, object, renderer, the light's
summary, time), the manifest it names (the scene's photograph) and ``eval.json``
(``zcomp eval``'s per-job metrics). ``OUT/preview/*.png`` (``zcomp preview-light``) are
listed as preview sheets.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from zcomp_cli.errors import UsageError
from zcomp_cli.preview.run import SUBDIR as PREVIEW_DIR  # where preview-light writes its sheets
from zcomp_cli.safe_read import MAX_JSON_BYTES, read_json_file, read_regular_bytes

# The order statuses are listed and sorted in.
STATUS_ORDER = ("done", "failed", "damaged", "changed", "missing")
EVAL_FILE = "eval.json"


@dataclass
class Collected:
    """What the page shows. ``rows``: one dict per job (see ``collect``); ``metrics``:
    the eval metrics that have a column, in eval.json's order; ``evaluation``: about the
    eval file (its name, protocol, means), None without one; ``previews``: one dict per
    preview sheet (``scene``, ``image`` and ``json``: paths); ``notes``: things skipped
    on the way (damaged files, an unreadable manifest)."""

    out: Path
    rows: list[dict] = field(default_factory=list)
    metrics: list[str] = field(default_factory=list)
    evaluation: dict | None = None
    previews: list[dict] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def counts(self) -> dict[str, int]:
        got: dict[str, int] = {}
        for r in self.rows:
            got[r["status"]] = got.get(r["status"], 0) + 1
        return {s: got[s] for s in sorted(got, key=status_rank)}


def status_rank(status: str) -> int:
    return STATUS_ORDER.index(status) if status in STATUS_ORDER else len(STATUS_ORDER)


def output_folder_problem(out) -> str | None:
    """Why ``out`` is not a zcomp output folder (None when it is one): it must be a
    folder holding a run summary (``summary*.json``) or a job folder with a
    ``report.json``."""
    out = Path(out)
    if not out.exists():
        return f"{out} does not exist"
    if not out.is_dir():
        return f"{out} is not a folder"
    try:
        entries = list(os.scandir(out))
    except OSError as exc:
        return f"{out}: cannot read the folder: {exc.strerror or exc}"
    if not entries:
        return f"{out} is empty: not a zcomp output folder (make one with `zcomp composite jobs.yaml --out {out}`)"
    if any(e.name.startswith("summary") and e.name.endswith(".json") and e.is_file() for e in entries):
        return None
    if any(e.is_dir() and os.path.isfile(os.path.join(e.path, "report.json")) for e in entries):
        return None
    return (f"{out} is not a zcomp output folder: no summary.json and no job folder with a report.json "
            f"(make one with `zcomp composite jobs.yaml --out {out}`)")


def collect(out, *, manifest=None, eval_file=None, verify: bool = False) -> Collected:
    """Gather the rows of ``out``. ``manifest``: a jobs.yaml whose jobs are all expected
    (those not there are ``missing``, as for ``zcomp status --manifest``) and whose
    scenes tell the backgrounds of jobs without a report; ``eval_file``: the eval.json
    (or eval.csv) to join (default ``OUT/eval.json``, else ``OUT/eval.csv``);
    ``verify``: hash every recorded output (default: sizes only).

    Each row: ``job``, ``status``, ``reason`` (failed, damaged), ``scene``, ``object``,
    ``renderer``, ``light`` (one line), ``light_note`` (the fallback's reason),
    ``light_uncertainty`` (degrees), ``seconds``, ``composite`` (path of composite.png
    or None), ``background`` (path of the scene's photograph or None) and ``metrics``
    (name -> float, +-inf or None). Raises ``UsageError`` when ``out`` is not a zcomp
    output folder."""
    from zcomp_cli.pipeline.outputs import read_report
    from zcomp_cli.pipeline.status import folder_status

    out = Path(out)
    problem = output_folder_problem(out)
    if problem:
        raise UsageError(problem)
    col = Collected(out=out)
    scenes = _SceneImages(col.notes)
    expected = None
    given = None
    if manifest is not None:
        from zcomp_cli.pipeline.manifest import load_manifest

        given = load_manifest(manifest, check_files=False)  # a ManifestError is the user's to see
        expected = [j.name for j in given.jobs]
        scenes.add(given)
    st = folder_status(out, expected, verify=verify)
    col.notes.extend(st.notes)
    status: dict[str, tuple[str, str | None]] = {}
    for n in st.done:
        status[n] = ("done", None)
    for n, why in st.failed.items():
        status[n] = ("failed", why)
    for n, why in st.damaged.items():
        status[n] = ("damaged", why)
    for n in st.changed:
        status[n] = ("changed", "made from other inputs than the manifest's now")
    for n in st.missing:
        status[n] = ("missing", None)
    seconds = _summary_seconds(out)

    pending = []  # rows without a usable report: their scene from a manifest, once all are known
    for name in sorted(status, key=_natural):
        state, reason = status[name]
        job_dir = out / name
        rep = read_report(job_dir) if _is(job_dir, os.path.isdir) else None
        row = {"job": name, "status": state, "reason": reason, "scene": None, "object": None,
               "renderer": None, "light": None, "light_note": None, "light_uncertainty": None,
               "seconds": seconds.get(name), "composite": None, "background": None, "metrics": {},
               "closeup": None}
        comp = job_dir / "composite.png"
        if state != "missing" and _is(comp, os.path.isfile):
            row["composite"] = comp
        if rep is not None:
            _from_report(row, rep, scenes, job_dir)
        else:
            pending.append(row)
        col.rows.append(row)
    if pending:
        jobs = scenes.jobs()
        for row in pending:
            j = jobs.get(row["job"])
            if j is not None:
                row["scene"], row["object"], man = j
                row["background"] = scenes.image(man, row["scene"])
    _join_eval(col, out, eval_file)
    col.previews = previews(out)
    return col


def _is(path: Path, test) -> bool:
    """``test(path)`` (``os.path.isdir``...), False where the path cannot even be asked
    about (a job name a summary lists that is longer than a file name may be)."""
    try:
        return test(path)
    except (OSError, ValueError):
        return False


def _natural(name: str):
    """Sort key: digit runs as numbers (job 10 after job 9)."""
    import re

    return [(0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", name) if t]


def _from_report(row: dict, rep: dict, scenes: "_SceneImages", job_dir: Path) -> None:
    job = rep.get("job") if isinstance(rep.get("job"), dict) else {}
    row["scene"] = _str(job.get("scene"))
    row["object"] = _str(job.get("object"))
    spec = rep.get("renderer_spec")
    rinfo = rep.get("renderer") if isinstance(rep.get("renderer"), dict) else {}
    settings = rinfo.get("settings") if isinstance(rinfo.get("settings"), dict) else {}
    row["renderer"] = _str(spec.get("name")) if isinstance(spec, dict) else None
    row["renderer"] = row["renderer"] or _str(settings.get("name"))
    row["light"], row["light_note"], row["light_uncertainty"] = light_summary(rep)
    row["closeup"] = _closeup(rep)
    timings = rep.get("timings") if isinstance(rep.get("timings"), dict) else {}
    t = _num(timings.get("job_total_s"))
    if t is not None:
        row["seconds"] = t
    man = job.get("manifest")
    if isinstance(man, str) and row["scene"]:
        path = Path(man)
        if not path.is_absolute():
            path = (job_dir / path)
        row["background"] = scenes.image(scenes.load(path, row["job"]), row["scene"])


def _closeup(rep: dict) -> list[int] | None:
    """[x0, y0, x1, y1, W, H]: the region the job re-shaded (its ``roi``: the object and
    its shadow) grown by a quarter of its size, in its W x H composite; None without
    one."""
    roi = rep.get("roi") if isinstance(rep.get("roi"), dict) else {}
    scene = rep.get("scene") if isinstance(rep.get("scene"), dict) else {}
    box, size = roi.get("box"), scene.get("size")
    try:
        x0, y0, x1, y1 = (int(v) for v in box)
        W, H = (int(v) for v in size)
    except (TypeError, ValueError):
        return None
    if not (0 <= x0 < x1 <= W and 0 <= y0 < y1 <= H) or W * H > 1e9:
        return None
    gx, gy = (x1 - x0) // 4, (y1 - y0) // 4
    return [max(0, x0 - gx), max(0, y0 - gy), min(W, x1 + gx), min(H, y1 + gy), W, H]


def _str(v) -> str | None:
    return v if isinstance(v, str) and v else None


def _num(v) -> float | None:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def _summary_seconds(out: Path) -> dict[str, float]:
    """name -> seconds of its latest attempt, from the summaries (oldest first, so the
    newest wins); damaged summaries are skipped (``folder_status`` notes them)."""
    found = []
    for p in out.glob("summary*.json"):
        try:
            found.append((p.stat().st_mtime, p.name, read_json_file(p)))
        except (OSError, ValueError):
            continue
    got: dict[str, float] = {}
    for _, _, doc in sorted(found, key=lambda t: (t[0], t[1])):
        jobs = doc.get("jobs") if isinstance(doc, dict) else None
        for j in jobs if isinstance(jobs, list) else []:
            if isinstance(j, dict) and isinstance(j.get("name"), str) and j.get("status") in ("done", "failed"):
                s = _num(j.get("seconds"))
                if s is not None:
                    got[j["name"]] = s
    return got


class _SceneImages:
    """The scene photographs of the manifests the reports name, each manifest read once
    (None, with a note, when it cannot be read: moved, edited into an invalid one)."""

    def __init__(self, notes: list[str]):
        self.notes = notes
        self.manifests: dict[str, object] = {}  # the path as a report names it -> manifest
        self.images: dict[tuple[int, str], Path | None] = {}

    def add(self, manifest) -> None:
        self.manifests[str(manifest.path)] = manifest

    def load(self, path: Path, job: str):
        key = str(path)
        if key not in self.manifests:
            try:
                from zcomp_cli.pipeline.manifest import load_manifest

                self.manifests[key] = load_manifest(path, check_files=False)
            except Exception as exc:  # noqa: BLE001 - an invalid manifest (edited since): its scenes' images
                why = " ".join(x.strip() for x in str(exc).splitlines()[:2]) or type(exc).__name__
                self.manifests[key] = _scene_images_only(path)
                what = ("its scenes' image entries are read as they are" if self.manifests[key] is not None
                        else "its jobs show no background")
                self.notes.append(f"manifest {path} (named by {job}/report.json) is not valid now, so {what}: {why}")
        return self.manifests[key]

    def image(self, manifest, scene: str | None) -> Path | None:
        if manifest is None or scene is None:
            return None
        key = (id(manifest), scene)
        if key not in self.images:
            spec = manifest.scenes.get(scene)
            self.images[key] = Path(spec.image) if spec is not None and Path(spec.image).is_file() else None
        return self.images[key]

    def jobs(self) -> dict[str, tuple[str, str, object]]:
        """job name -> (scene, object, manifest) over every manifest read."""
        got = {}
        for m in self.manifests.values():
            for j in m.jobs if m is not None else []:
                got.setdefault(j.name, (j.scene, j.object, m))
        return got


class _Scenes:
    """What an invalid manifest still tells: each scene's ``image`` (relative to the
    manifest's folder, as the manifest resolves it); no jobs."""

    def __init__(self, path: Path, images: dict[str, Path]):
        from types import SimpleNamespace

        self.path = path
        self.scenes = {k: SimpleNamespace(image=v) for k, v in images.items()}
        self.jobs: list = []


def _scene_images_only(path: Path) -> _Scenes | None:
    try:
        from zcomp_cli.yamlloc import load_yaml

        doc = load_yaml(Path(path))
        scenes = doc.get("scenes") if isinstance(doc, dict) else None
        images = {}
        for name, sc in (scenes.items() if isinstance(scenes, dict) else []):
            img = sc.get("image") if isinstance(sc, dict) else None
            if isinstance(name, str) and isinstance(img, str) and img and "\0" not in img:
                images[name] = Path(img) if Path(img).is_absolute() else (Path(path).parent / img).resolve()
        return _Scenes(Path(path), images) if images else None
    except Exception:  # noqa: BLE001 - not even YAML any more
        return None


# ------------------------------------------------------------------ the light
def light_summary(report: dict) -> tuple[str | None, str | None, float | None]:
    """(one line, the fallback's reason, the direction's uncertainty in degrees) of the
    light a job was rendered with, from its report (``light``, or the renderer's
    ``info.light`` as the physical and Cycles renderers write it), in an artist's words.
    E.g. ``"sun at azimuth 120°, elevation 35°, estimated from the photograph, ±12°"``;
    ``"..., simplified (hover for why)"`` when the renderer fell back (the reason is the
    note). (None, None, None) when the report has none (the naive and zerocomp
    renderers)."""
    info = {}
    r = report.get("renderer")
    if isinstance(r, dict) and isinstance(r.get("info"), dict):
        info = r["info"]
    light = report.get("light") if isinstance(report.get("light"), dict) else info.get("light")
    if not isinstance(light, dict):
        return None, None, None
    kinds = [x.get("kind") for x in light.get("lights") or [] if isinstance(x, dict)]
    key = next((k for k in kinds if k in ("sun", "lamp")), None)
    parts = []
    angles = _angles(light.get("direction"), light.get("up_camera"))
    if angles is not None:
        az, el = angles
        parts.append(f"{key or 'light'} at azimuth {az}°, elevation {el}°")
    elif key:
        parts.append(key)
    elif "sky" in kinds:
        parts.append("sky only")
    src = light.get("source")
    if isinstance(src, str) and src:
        parts.append(_SOURCE_WORDS.get(src, src))
    fit = light.get("fit") if isinstance(light.get("fit"), dict) else {}
    unc = _num(fit.get("direction_uncertainty_deg"))
    if unc is not None:
        parts.append(f"±{unc:.0f}°")
    if fit.get("unfixed") is True:
        modes = fit.get("modes") if isinstance(fit.get("modes"), list) else []
        parts.append("direction a guess (the photograph does not fix it)" if len(modes) < 2 else
                     f"direction a guess (the photograph does not fix it): drawn as its {len(modes)} likeliest lights")
    shadow = light.get("shadow")
    if isinstance(shadow, str) and shadow and shadow != "cast shadow":
        parts.append(shadow)
    fallback = light.get("fallback") or info.get("fallback")
    note = str(fallback) if fallback else None
    if note:
        parts.append("simplified (hover for why)")
    return (", ".join(parts) or None), note, unc


# where the light came from, in an artist's words
_SOURCE_WORDS = {"estimated": "estimated from the photograph", "manifest": "given in the manifest"}


_ANGLES: dict[tuple, tuple[int, int] | None] = {}  # the jobs of a scene share their light


def _angles(direction, up) -> tuple[int, int] | None:
    """(azimuth, elevation) in whole degrees on the ground (``worldframe``: azimuth 0 =
    the camera's right, 90 = away from the camera), or None without a usable pair."""
    from zcomp_cli.worldframe import angles_from_direction

    try:
        if not (isinstance(direction, list) and isinstance(up, list) and len(direction) == 3 and len(up) == 3):
            return None
        key = (*(float(x) for x in direction), *(float(x) for x in up))
    except (TypeError, ValueError):
        return None
    if key not in _ANGLES:
        try:
            az, el = angles_from_direction(key[:3], key[3:])
            _ANGLES[key] = (round(az) % 360, round(el)) if math.isfinite(az) and math.isfinite(el) else None
        except (TypeError, ValueError):
            _ANGLES[key] = None
        if len(_ANGLES) > 100_000:
            _ANGLES.clear()
    return _ANGLES[key]


# ------------------------------------------------------------------ zcomp eval
def _join_eval(col: Collected, out: Path, eval_file) -> None:
    if eval_file is None:
        path = out / EVAL_FILE
        if not path.is_file() and (out / "eval.csv").is_file():
            path = out / "eval.csv"
        if not path.is_file():
            return
    else:
        path = Path(eval_file)
        if not path.is_file():
            raise UsageError(f"--eval: {path} is not a file")
    try:
        metrics, values, about = (_read_eval_csv if path.suffix.lower() == ".csv" else _read_eval_json)(path)
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError) as exc:
        if eval_file is not None:
            raise UsageError(f"--eval: {path} is not an eval.json or eval.csv of `zcomp eval` ({exc})") from exc
        col.notes.append(f"{path.name}: not readable as `zcomp eval` output ({type(exc).__name__}); no metrics shown")
        return
    by_name = {r["job"]: r for r in col.rows}
    joined = 0
    for name, vals in values.items():
        row = by_name.get(name) or by_name.get(name.split("/", 1)[0])  # two-folder mode: "job/composite"
        if row is not None:
            row["metrics"].update(vals)
            joined += 1
    col.metrics = metrics
    col.evaluation = {"file": path, "scored": len(values), "joined": joined, **about}


def _metric_value(v):
    """A metric as eval.json writes it: a number, "inf"/"-inf" or null."""
    if v in ("inf", "-inf"):
        return math.inf if v == "inf" else -math.inf
    if isinstance(v, str):
        try:
            v = float(v)
        except ValueError:
            return None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    return None if math.isnan(v) else float(v)


def _read_eval_json(path: Path):
    doc = read_json_file(path)
    unavailable = doc.get("unavailable") or {}
    metrics = [m for m in doc["metrics"] if isinstance(m, str) and m not in unavailable]
    values = {}
    for img in doc["images"]:
        values[str(img["name"])] = {m: _metric_value(img.get(m)) for m in metrics}
    prot = doc.get("protocol") if isinstance(doc.get("protocol"), dict) else {}
    mean = doc.get("mean") if isinstance(doc.get("mean"), dict) else {}
    about = {"protocol": prot.get("name"), "encoding": prot.get("encoding") or doc.get("colour_space"),
             "region": prot.get("region"), "mean": {m: _metric_value(mean.get(m)) for m in metrics},
             "unscored": len(doc.get("unscored") or {}), "unavailable": dict(unavailable)}
    return metrics, values, about


def _read_eval_csv(path: Path):
    import io

    text = read_regular_bytes(path, MAX_JSON_BYTES, "CSV file").decode("utf-8")
    try:
        rows = list(csv.reader(io.StringIO(text, newline="")))
    except csv.Error as exc:  # (a field over the csv module's 128 KiB)
        raise ValueError(f"not a CSV file zcomp eval writes: {exc}") from None
    if not rows:
        raise ValueError("the file is empty")
    head = rows[0]
    if head[:3] != ["name", "pred", "ref"]:
        raise ValueError("its header is not name,pred,ref,<metrics>")
    metrics = head[3:]
    values, mean = {}, {}
    for r in rows[1:]:
        vals = {m: _metric_value(x) if x != "" else None for m, x in zip(metrics, r[3:])}
        if r and r[0] == "mean":
            mean = vals
        elif r:
            values[r[0]] = vals
    return metrics, values, {"mean": mean}


# ------------------------------------------------------------------ preview sheets
def previews(out: Path) -> list[dict]:
    """``OUT/preview/<scene>.png`` (and ``<scene>.json`` beside it when there is one,
    with the light's one-line summary), sorted by scene."""
    folder = Path(out) / PREVIEW_DIR
    if not folder.is_dir():
        return []
    found = []
    for p in sorted(folder.glob("*.png"), key=lambda p: _natural(p.stem)):
        if p.name.startswith(".") or not p.is_file():  # a temporary being written
            continue
        js = p.with_suffix(".json")
        light = None
        if js.is_file():
            try:
                doc = read_json_file(js)
                if isinstance(doc, dict) and isinstance(doc.get("light"), dict):
                    light = light_summary({"light": doc["light"]})[0]
            except (OSError, ValueError):
                pass
        found.append({"scene": p.stem, "image": p, "json": js if js.is_file() else None, "light": light})
    return found


__all__ = ["Collected", "STATUS_ORDER", "collect", "light_summary", "output_folder_problem", "previews",
           "status_rank"]
