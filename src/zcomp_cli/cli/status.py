"""``zcomp status OUT``: one summary of an output folder, over every run and shard."""

from __future__ import annotations

import click

NAME_CHARS = 200  # a job name shown (a summary may list any text as one)


@click.command("status")
@click.argument("out_dir", type=click.Path(file_okay=False))
@click.option("--manifest", type=click.Path(dir_okay=False), default=None,
              help="jobs.yaml: count its jobs that are in no summary yet as missing, and its finished jobs "
                   "made from other inputs than the manifest's now as changed (as --resume judges them).")
@click.option("--jobs", "jobs_subset", default=None, metavar="SUBSET",
              help="With --manifest: only these jobs (as for composite).")
@click.option("--sizes-only", is_flag=True,
              help="Check the outputs' sizes, not their sha256 (faster on a big folder).")
@click.option("--json", "as_json", is_flag=True, help="Print the merged state as JSON.")
@click.pass_context
def status(ctx, out_dir, manifest, jobs_subset, sizes_only, as_json):
    """Merge OUT's job reports and run/shard summaries: done, failed (with reasons),
    missing, damaged (outputs missing or altered) and changed (made from other inputs)
    jobs. Exit code 0 when every expected job is done, 1 otherwise."""
    import json

    from zcomp_cli.pipeline.status import folder_status

    expected = fingerprints = None
    if manifest is not None:
        expected, fingerprints = _expected(manifest, jobs_subset)
    st = folder_status(out_dir, expected, fingerprints=fingerprints, verify=not sizes_only)
    if as_json:
        click.echo(json.dumps(st.to_dict(), indent=2))
    else:
        from rich.console import Console
        from rich.markup import escape

        from zcomp_cli.limits import field_text

        console = Console()
        console.print(f"{field_text(out_dir)}: {len(st.done)} done, {len(st.failed)} failed, {len(st.missing)} missing, "
                      f"{len(st.damaged)} damaged, {len(st.changed)} changed", highlight=False)
        for k, v in st.shards.items():
            console.print(f"  shard {k}: {v}")
        for title, colour, rows in (("failed", "red", st.failed.items()), ("damaged", "red", st.damaged.items()),
                                    ("changed", "yellow", ((n, "made from other inputs (--resume --redo-changed "
                                                                "redoes it)") for n in st.changed)),
                                    ("missing", "yellow", ((n, None) for n in st.missing))):
            rows = list(rows)
            for name, reason in rows[:50]:
                console.print(f"  [{colour}]{title}[/] {escape(field_text(name, NAME_CHARS))}"
                              f"{': ' + escape(field_text(reason)) if reason else ''}", highlight=False)
            if len(rows) > 50:
                console.print(f"  ... and {len(rows) - 50} more {title}")
        for note in st.notes[:20]:
            console.print(f"  [yellow]note[/] {escape(field_text(note))}", highlight=False)
    if not st.complete:
        ctx.exit(1)


def _expected(manifest, jobs_subset):
    """The manifest's (selected) job names, and per job the fingerprint it has now, made
    with the renderer its report says it was made with (command-line overrides
    included; reports without it: the manifest's renderer)."""
    from zcomp_cli.cache import cache_root
    from zcomp_cli.pipeline.fingerprint import job_fingerprint
    from zcomp_cli.pipeline.manifest import RendererSpec, load_manifest
    from zcomp_cli.pipeline.outguard import DigestCache
    from zcomp_cli.pipeline.selection import select_jobs

    m = load_manifest(manifest)
    jobs = select_jobs(m.jobs, jobs_subset)
    digests = DigestCache(cache_root() / "file-hashes.json")

    def fingerprint_of(job):
        def fp(report: dict) -> str:
            rs = report.get("renderer_spec")
            spec = m.defaults.renderer
            if isinstance(rs, dict) and isinstance(rs.get("name"), str) and isinstance(rs.get("settings"), dict):
                spec = RendererSpec(rs["name"], dict(rs["settings"]))
            return job_fingerprint(m, job, spec, m.defaults.samples, digests)
        return fp

    return [j.name for j in jobs], {j.name: fingerprint_of(j) for j in jobs}
