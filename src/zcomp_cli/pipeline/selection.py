"""Which jobs of a manifest a run takes: the ``--jobs`` subset syntax."""

from __future__ import annotations

from zcomp_cli.errors import UsageError
from zcomp_cli.pipeline.manifest import JobSpec


def select_jobs(jobs: list[JobSpec], subset: str | None) -> list[JobSpec]:
    """``--jobs`` syntax: comma-separated indices, ranges ``a-b`` and job names.

    Returns the picked jobs in manifest order (each once). Raises UsageError for a part
    that is neither an index, a range nor a name, or for an index out of range.
    """
    if not subset:
        return list(jobs)
    by_name = {j.name: j for j in jobs}
    picked: dict[int, JobSpec] = {}
    for part in (p.strip() for p in subset.split(",") if p.strip()):
        if part in by_name:
            picked[by_name[part].index] = by_name[part]
            continue
        try:
            if "-" in part:
                a, b = (int(v) for v in part.split("-", 1))
                rng = range(a, b + 1)
            else:
                rng = range(int(part), int(part) + 1)
        except ValueError:
            raise UsageError(f"--jobs: {part!r} is neither a job index, a range a-b, nor a job name") from None
        for i in rng:
            if not 0 <= i < len(jobs):
                raise UsageError(f"--jobs: index {i} out of range (the manifest has {len(jobs)} jobs)")
            picked[i] = jobs[i]
    return [picked[i] for i in sorted(picked)]
