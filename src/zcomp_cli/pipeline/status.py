"""The state of an output folder, merged over every run and shard that wrote to it.

Sources, in ``OUT/``: each job folder's ``report.json`` with the outputs it records (the
truth), and the summaries (``summary.json``, ``summary.shard-I-of-N.json``): they list
the jobs each run or shard took, and why the failed ones failed. Each job is judged as
``--resume`` judges it (``outputs.job_state``):

* ``done``: its report says done and every output it records is intact (sizes and
  sha256), and, when a manifest is given, it was made from the manifest's current inputs;
* ``damaged``: its report says done, but an output is missing, empty or altered
  (``--resume`` redoes it);
* ``changed``: done, but made from other inputs or settings than the manifest's now
  (``--resume --redo-changed`` redoes it);
* ``failed``: a summary says so and no report says done (the newest summary's reason wins);
* ``missing``: expected -- listed by a shard, or in the manifest when one is given -- but
  none of the above.

Damaged summaries and reports (not JSON, or JSON of another shape) are skipped with a
note; a shard count beyond ``MAX_SHARD_COUNT`` marks its summary damaged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from zcomp_cli.errors import UsageError
from zcomp_cli.limits import field_text
from zcomp_cli.pipeline.outputs import job_state
from zcomp_cli.pipeline.selection import MAX_SHARD_COUNT
from zcomp_cli.safe_read import JsonFileError, read_json_file


@dataclass
class FolderStatus:
    done: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)  # name -> reason
    missing: list[str] = field(default_factory=list)
    damaged: dict[str, str] = field(default_factory=dict)  # name -> what is wrong with its outputs
    changed: list[str] = field(default_factory=list)  # made from other inputs than the manifest's
    shards: dict = field(default_factory=dict)  # "i/n" -> "finished" | "no summary"
    summaries: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # damaged files that were skipped

    @property
    def complete(self) -> bool:
        """Every expected job done, and every shard seen has written its summary."""
        return (not self.failed and not self.missing and not self.damaged and not self.changed
                and all(v == "finished" for v in self.shards.values()))

    def to_dict(self) -> dict:
        return {"done": len(self.done), "failed": len(self.failed), "missing": len(self.missing),
                "damaged": len(self.damaged), "changed": len(self.changed),
                "complete": self.complete, "shards": self.shards, "summaries": self.summaries,
                "notes": self.notes,
                "jobs": {"done": self.done, "failed": self.failed, "missing": self.missing,
                         "damaged": self.damaged, "changed": self.changed}}


def _int(v) -> int | None:
    return int(v) if isinstance(v, int) and not isinstance(v, bool) else None


def _summaries(out: Path, notes: list[str]) -> list[tuple[float, Path, dict]]:
    """Every summary of ``out`` that has the shape zcomp writes, oldest first."""
    found = []
    for p in sorted(out.glob("summary*.json")):
        try:
            doc = read_json_file(p)
            mtime = p.stat().st_mtime
        except JsonFileError as exc:
            notes.append(f"{p.name}: {exc}; skipped")
            continue
        except (OSError, ValueError):
            continue  # a summary being replaced right now: the reports still tell
        problem = _summary_problem(doc)
        if problem:
            notes.append(f"{p.name}: {problem}; skipped")
            continue
        found.append((mtime, p, doc))
    return sorted(found, key=lambda t: (t[0], t[1].name))


def _summary_problem(doc) -> str | None:
    if not isinstance(doc, dict):
        return f"holds {type(doc).__name__}, not a summary"
    jobs = doc.get("jobs")
    if jobs is not None and not (isinstance(jobs, list) and all(
            isinstance(j, dict) and isinstance(j.get("name"), str) for j in jobs)):
        return "its 'jobs' is not a list of jobs with names"
    shard = doc.get("shard")
    if shard is not None:
        if not isinstance(shard, dict):
            return "its 'shard' is not a mapping"
        i, n = _int(shard.get("index")), _int(shard.get("count"))
        if i is None or n is None or not 0 <= i < n:
            return "its 'shard' has no valid index and count"
        if n > MAX_SHARD_COUNT:
            return f"its shard count {n} is over {MAX_SHARD_COUNT}"
        names = shard.get("jobs")
        if names is not None and not (isinstance(names, list) and all(isinstance(x, str) for x in names)):
            return "its 'shard.jobs' is not a list of names"
    return None


def folder_status(out, expected: list[str] | None = None, *, fingerprints: dict[str, object] | None = None,
                  verify: bool = True) -> FolderStatus:
    """Merge ``out``'s reports and summaries. ``expected``: every job name that should
    be there (e.g. the manifest's); without it, the jobs the summaries list.
    ``fingerprints``: name -> ``fingerprint(report) -> str``, the fingerprint the job
    would have now (a job made from other inputs is then ``changed``). ``verify``:
    hash every recorded output (False: sizes only)."""
    out = Path(out)
    if not out.is_dir():
        raise UsageError(f"{out} is not a folder")
    st = FolderStatus()
    reasons: dict[str, str] = {}
    listed: list[str] = []
    counts = set()
    seen_shards = set()
    for _, p, summ in _summaries(out, st.notes):
        st.summaries.append(p.name)
        shard = summ.get("shard")
        if shard:
            counts.add(int(shard["count"]))
            seen_shards.add((int(shard["index"]), int(shard["count"])))
            listed.extend(shard.get("jobs") or [])
        for j in summ.get("jobs") or []:
            listed.append(j["name"])
            if j.get("status") == "failed":
                reasons[j["name"]] = field_text(j.get("reason") or "failed")  # later summaries win
            elif j.get("status") in ("done", "skipped"):
                reasons.pop(j["name"], None)
    for n in sorted(counts):
        for i in range(n):
            st.shards[f"{i}/{n}"] = "finished" if (i, n) in seen_shards else "no summary"
    names = list(dict.fromkeys(expected if expected is not None else listed))
    if expected is None:  # job folders nobody listed (a run killed before its summary)
        known = set(names)  # (a set: a list's membership test made this quadratic in the jobs)
        names += [d.name for d in sorted(out.iterdir()) if d.is_dir() and d.name not in known
                  and (d / "report.json").exists()]
    for name in names:
        js = job_state(out / name, verify=verify)
        if js.note:
            st.notes.append(js.note)
        if js.state == "done" and fingerprints is not None and name in fingerprints:
            if js.report.get("fingerprint") != fingerprints[name](js.report):
                st.changed.append(name)
                continue
        if js.state == "done":
            st.done.append(name)
        elif js.state == "damaged":
            st.damaged[name] = js.reason or "damaged"
        elif name in reasons:
            st.failed[name] = reasons[name]
        else:
            st.missing.append(name)
    return st
