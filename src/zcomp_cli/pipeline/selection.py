"""Which jobs of a manifest a run takes: the ``--jobs`` subset syntax."""

from __future__ import annotations

import heapq

from zcomp_cli.errors import UsageError
from zcomp_cli.pipeline.manifest import JobSpec

# The most shards a batch may be cut into (a job array of a million tasks is a typo);
# `zcomp status` treats a summary claiming more as damaged.
MAX_SHARD_COUNT = 100_000


def select_jobs(jobs: list[JobSpec], subset: str | None) -> list[JobSpec]:
    """``--jobs`` syntax: comma-separated indices, ranges ``a-b`` and job names.

    Returns the picked jobs in manifest order (each once). Raises UsageError for a part
    that is neither an index, a range nor a name, or for an index out of range.
    """
    if subset is None:
        return list(jobs)
    parts = [p.strip() for p in subset.split(",")]
    if not any(parts):
        raise UsageError(f"--jobs: {subset!r} names no job (give indices, ranges a-b or job names)")
    by_name = {j.name: j for j in jobs}
    picked: dict[int, JobSpec] = {}
    for part in (p for p in parts if p):
        if part in by_name:
            picked[by_name[part].index] = by_name[part]
            continue
        try:
            if "-" in part:
                a, b = (int(v) for v in part.split("-", 1))
                if b < a:
                    raise UsageError(f"--jobs: range {part!r} is backwards (write {b}-{a})")
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


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """``--shard i/n`` -> ``(i, n)`` with ``0 <= i < n`` (shards count from 0), or None."""
    if text is None:
        return None
    try:
        a, b = text.split("/")
        i, n = int(a), int(b)
    except ValueError:
        raise UsageError(f"--shard: expected I/N such as 0/3, got {text!r}") from None
    if n < 1 or not 0 <= i < n:
        raise UsageError(f"--shard: need N >= 1 and 0 <= I < N (shards count from 0), got {text!r}")
    if n > MAX_SHARD_COUNT:
        raise UsageError(f"--shard: at most {MAX_SHARD_COUNT:,} shards, got {n:,}")
    return i, n


def shard_jobs(jobs: list[JobSpec], index: int, count: int) -> list[JobSpec]:
    """The jobs of shard ``index`` of ``count``: a deterministic partition of ``jobs``.

    Jobs sharing a scene stay together, so a shard loads (and estimates) each scene at
    most once. A scene with more than ``ceil(len(jobs) / count)`` jobs is cut into runs
    of that size, else one busy scene would leave the other shards idle. The pieces go,
    largest first, to the shard with the fewest jobs so far (ties: lowest shard, then
    first scene in manifest order), so every shard computes the same partition from
    the same selected jobs. Returns the shard's jobs in manifest order.
    """
    if count < 1 or not 0 <= index < count:
        raise UsageError(f"shard {index}/{count} does not exist")
    if count == 1:
        return list(jobs)
    cap = max(1, -(-len(jobs) // count))
    by_scene: dict[str, list[JobSpec]] = {}
    for j in jobs:
        by_scene.setdefault(j.scene, []).append(j)
    pieces = []  # (size, order, jobs)
    for order, group in enumerate(by_scene.values()):
        for k in range(0, len(group), cap):
            pieces.append((len(group[k:k + cap]), order * 10**6 + k, group[k:k + cap]))
    pieces.sort(key=lambda p: (-p[0], p[1]))
    # The least-loaded shard (lowest index on ties), in O(log) per piece: shards not used
    # yet have load 0 and beat every used one (a piece holds at least one job), so they
    # are taken in index order; the used ones sit in a heap. Never O(jobs x shards).
    used: list[tuple[int, int]] = []  # (load, shard)
    fresh = 0  # the lowest shard not used yet
    mine: list[JobSpec] = []
    for size, _, piece in pieces:
        if fresh < count:
            s, fresh = fresh, fresh + 1
            heapq.heappush(used, (size, s))
        else:
            load, s = heapq.heappop(used)
            heapq.heappush(used, (load + size, s))
        if s == index:
            mine.extend(piece)
    return sorted(mine, key=lambda j: j.index)
