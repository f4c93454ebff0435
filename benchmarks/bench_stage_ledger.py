"""The shipped example's jobs stage by stage (issue 49): what each job ran, what it
skipped and why, and how long each stage took -- the light given (job 4: the room's probe
and sun) against the light estimated (job 0: the same vase, the same pose).

    python benchmarks/bench_stage_ledger.py [--repeat 3] [--cycles] [--doc docs/stage-ledger.md]

Three runs into fresh output folders, one cache (a temporary ``--cache-dir``):

1. **cold**: nothing cached: Blender renders the objects' passes, each scene's light is
   fitted;
2. **fitted** (``--repeat`` times, the median figures): the objects' passes cached
   (Blender is not started), the lights' cache emptied before each run: every scene's
   light is fitted again -- the run the target is measured on (a job whose maps and
   light are given spends under 10 % of its time in fitting);
3. **warm**: everything cached: no Blender, no fit.

``--cycles`` adds job 4 under the ``cycles`` renderer (16 samples): the light given is
not searched, and no glossy prefilter is built (the path tracer reads the probe itself).
Prints each job's ledger (``report.json``'s ``stages``) and the light stage's share of
the job; ``--doc`` writes the tables into a markdown page (between its markers).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "examples" / "jobs.yaml"
GIVEN, ESTIMATED = "004_room_lit_vase", "000_room_vase"


def run(out: Path, cache: Path, *, renderer: str | None = None, jobs: str | None = None) -> dict:
    """One ``zcomp composite`` of the shipped example in a process of its own (the
    in-process caches -- a split probe, a prefiltered sky -- start empty, as a user's run
    does): {job: its report}, and the batch's Blender figures under ``"_blender"``."""
    import subprocess

    cmd = [sys.executable, "-m", "zcomp_cli", "-q", "composite", str(MANIFEST), "--out", str(out), "--cache-dir",
           str(cache), "--overwrite"]
    if renderer:
        cmd += ["--renderer", renderer, "--samples", "16"]
    if jobs:
        cmd += ["--jobs", jobs]
    subprocess.run(cmd, check=True)
    summary = json.loads((out / "summary.json").read_text())
    reports = {p.parent.name: json.loads(p.read_text()) for p in sorted(out.glob("*/report.json"))}
    reports["_blender"] = dict(summary.get("blender") or {})
    return reports


def share(report: dict) -> dict:
    """The light stage's seconds, the fit proper's (the light stage less reading a given
    probe), the job's (its stages summed) and the shares."""
    from zcomp_cli.pipeline.ledger import fit_share

    out = fit_share(report["stages"])
    probe = sum(e["seconds"] or 0.0 for e in report["stages"] if e["stage"] == "light.probe")
    out["fit_s"] = out["light_s"] - probe
    out["fit_share"] = out["fit_s"] / out["total_s"] if out["total_s"] > 0 else float("nan")
    return out


def ledger_table(report: dict, title: str) -> list[str]:
    lines = [f"**{title}** ({report['job']['name']}, {report['renderer']['settings']['name']})", "",
             "| stage | status | why / what | seconds |", "| --- | --- | --- | --- |"]
    for e in report["stages"]:
        why = e.get("why") or e.get("what") or ""
        sec = "" if e.get("seconds") is None else f"{e['seconds']:.3f}"
        lines.append(f"| {e['stage']} | {e['status']} | {why} | {sec} |")
    return lines + [""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cycles", action="store_true")
    ap.add_argument("--doc", type=Path, default=None)
    a = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="zcomp-ledger-"))
    cache = work / "cache"
    try:
        cold = run(work / "cold", cache)
        fitted = []
        for k in range(max(1, a.repeat)):
            shutil.rmtree(cache / "lights", ignore_errors=True)
            fitted.append(run(work / f"fitted{k}", cache))
        warm = run(work / "warm", cache)
        cyc = run(work / "cycles", cache, renderer="cycles", jobs="4") if a.cycles else None
    finally:
        shutil.rmtree(work, ignore_errors=True)
    lines = _summary(cold, fitted, warm)
    lines += ["", "### The ledgers (the first fitted run)", ""]
    lines += ledger_table(fitted[0][ESTIMATED], "light estimated")
    lines += ledger_table(fitted[0][GIVEN], "light given")
    lines += ledger_table(fitted[0]["001_room_crate"], "light estimated, the scene's second job")
    lines += ledger_table(warm[GIVEN], "light given, everything cached")
    if cyc is not None:
        lines += ledger_table(cyc[GIVEN], "light given, the cycles renderer")
    text = "\n".join(lines)
    print(text)
    if a.doc is not None:  # (between its markers: the page's prose is kept)
        from stability_sweep import write_doc

        write_doc(a.doc, text, "stage ledger tables")
    return 0


def _summary(cold, fitted, warm) -> list[str]:
    lines = ["| run | job | light | light s | fit s (less the probe) | job s | light share | fit share |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, runs in (("cold", [cold]), (f"fitted (median of {len(fitted)})", fitted), ("warm", [warm])):
        for job, what in ((ESTIMATED, "estimated"), (GIVEN, "given")):
            figs = [share(r[job]) for r in runs]
            med = {k: statistics.median(f[k] for f in figs) for k in figs[0]}
            lines.append(f"| {name} | {job} | {what} | {med['light_s']:.3f} | {med['fit_s']:.3f} | {med['total_s']:.3f} "
                         f"| {100 * med['share']:.1f} % | {100 * med['fit_share']:.1f} % |")
    b = [("cold", cold["_blender"]), ("fitted", fitted[0]["_blender"]), ("warm", warm["_blender"])]
    lines += ["", "Blender (the objects' passes): " + "; ".join(
        f"{n}: {d.get('requests', 0)} asked, {d.get('cached', 0)} cached"
        f"{', Blender started' if d.get('requests', 0) > d.get('cached', 0) else ', Blender not started'}"
        for n, d in b)]
    return lines


if __name__ == "__main__":
    sys.exit(main())
