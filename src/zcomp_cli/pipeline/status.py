"""The state of an output folder, merged over every run and shard that wrote to it.

Sources, in ``OUT/``: each job folder's ``report.json`` (``status: done`` marks a
finished job: the truth), and the summaries (``summary.json``,
``summary.shard-I-of-N.json``): they list the jobs each run or shard took, and why the
failed ones failed. A job is ``done`` (its report says so), ``failed`` (a summary says
so and no report says done; the most recent summary's reason wins) or ``missing``
(expected -- listed by a shard, or in the manifest when one is given -- but neither).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from zcomp_cli.errors import UsageError
from zcomp_cli.pipeline.outputs import read_report


@dataclass
class FolderStatus:
    done: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)  # name -> reason
    missing: list[str] = field(default_factory=list)
    shards: dict = field(default_factory=dict)  # "i/n" -> "finished" | "no summary"
    summaries: list[str] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        """Every expected job done, and every shard seen has written its summary."""
        return not self.failed and not self.missing and all(v == "finished" for v in self.shards.values())

    def to_dict(self) -> dict:
        return {"done": len(self.done), "failed": len(self.failed), "missing": len(self.missing),
                "complete": self.complete, "shards": self.shards, "summaries": self.summaries,
                "jobs": {"done": self.done, "failed": self.failed, "missing": self.missing}}


def _summaries(out: Path) -> list[tuple[float, Path, dict]]:
    found = []
    for p in sorted(out.glob("summary*.json")):
        try:
            found.append((p.stat().st_mtime, p, json.loads(p.read_text())))
        except (OSError, json.JSONDecodeError):
            continue  # a summary being replaced right now: the reports still tell
    return sorted(found, key=lambda t: (t[0], t[1].name))


def folder_status(out, expected: list[str] | None = None) -> FolderStatus:
    """Merge ``out``'s reports and summaries. ``expected``: every job name that should
    be there (e.g. the manifest's); without it, the jobs the summaries list."""
    out = Path(out)
    if not out.is_dir():
        raise UsageError(f"{out} is not a folder")
    st = FolderStatus()
    reasons: dict[str, str] = {}
    listed: list[str] = []
    counts = set()
    seen_shards = set()
    for _, p, summ in _summaries(out):
        st.summaries.append(p.name)
        shard = summ.get("shard")
        if shard:
            counts.add(int(shard["count"]))
            seen_shards.add((int(shard["index"]), int(shard["count"])))
            listed.extend(shard.get("jobs") or [])
        for j in summ.get("jobs") or []:
            listed.append(j["name"])
            if j.get("status") == "failed":
                reasons[j["name"]] = j.get("reason") or "failed"  # later summaries win
            elif j.get("status") in ("done", "skipped"):
                reasons.pop(j["name"], None)
    for n in sorted(counts):
        for i in range(n):
            st.shards[f"{i}/{n}"] = "finished" if (i, n) in seen_shards else "no summary"
    names = list(dict.fromkeys(expected if expected is not None else listed))
    if expected is None:  # job folders nobody listed (a run killed before its summary)
        names += [d.name for d in sorted(out.iterdir()) if d.is_dir() and (d / "report.json").exists()
                  and d.name not in names]
    for name in names:
        rep = read_report(out / name)
        if rep is not None and rep.get("status") == "done":
            st.done.append(name)
        elif name in reasons:
            st.failed[name] = reasons[name]
        else:
            st.missing.append(name)
    return st
