"""``zcomp eval``: score composites against references (PSNR, RMSE, si-RMSE, SSIM, MAE,
LPIPS, FLIP); per-image values and means to eval.csv / eval.json and a table."""

from __future__ import annotations

import click

_METRICS_HELP = ("Comma-separated: psnr,rmse,si-rmse,ssim,mae,lpips,flip,shadow-iou,shadow-darkness "
                 "or all.")


def _check_metrics(ctx, param, value):
    from zcomp_cli.errors import UsageError
    from zcomp_cli.metrics.evaluate import parse_metrics

    try:
        return parse_metrics(value)
    except UsageError as exc:
        raise click.BadParameter(str(exc), ctx=ctx, param=param) from exc


@click.command("eval")
@click.argument("pred", type=click.Path(exists=True, file_okay=False))
@click.argument("ref", type=click.Path(exists=True, file_okay=False), required=False)
@click.option("--metrics", default="all", show_default=True, callback=_check_metrics, help=_METRICS_HELP)
@click.option("--refs", "refs_dir", type=click.Path(exists=True, file_okay=False), default=None,
              help="Composite output mode: folder of references named after the jobs.")
@click.option("--linear", is_flag=True,
              help="Pixel metrics on linear values instead of sRGB-encoded [0, 1] (LPIPS and "
                   "LDR FLIP stay on sRGB).")
@click.option("--mask", default=None, metavar="PATH|NAME",
              help="Score only a region: a folder of masks (matched like the images), a mask "
                   "file, or a file name inside each job folder (e.g. shading_mask.png).")
@click.option("--background", "background", type=click.Path(exists=True), default=None,
              help="Shadow metrics: the background photograph(s) composited into (a file, or a folder "
                   "matched like the images). Default for a composite output folder: each job's scene "
                   "image, read from the manifest its report.json names.")
@click.option("--out", "out_prefix", type=click.Path(dir_okay=False), default=None, metavar="PATH_PREFIX",
              help="Write PATH_PREFIX.csv and PATH_PREFIX.json (default PRED/eval.*).")
@click.option("--lpips-backbone", type=click.Path(dir_okay=False), default=None,
              help="torchvision AlexNet state dict (alexnet-owt-7be5be79.pth); env ZCOMP_LPIPS_BACKBONE. "
                   "Default: fetched once into zcomp's cache and checked (ZCOMP_OFFLINE=1: never).")
@click.option("--lpips-weights", type=click.Path(dir_okay=False), default=None,
              help="LPIPS v0.1 linear weights (lpips' weights/v0.1/alex.pth); env ZCOMP_LPIPS_WEIGHTS. "
                   "Default: an installed lpips package's, else fetched once into zcomp's cache.")
@click.option("--protocol", type=click.Choice(["paper", "zcomp"]), default=None,
              help="paper: the ZeroComp paper's (gamma-2.2 display encoding; psnr, rmse, si-rmse, ssim, mae, "
                   "lpips, flip); "
                   "zcomp: sRGB. Default: paper when every reference was written by `zcomp import`.")
@click.option("--region", type=click.Choice(["full", "object-crop"]), default="full", show_default=True,
              help="object-crop: the object's box grown by 25% on each side (object_mask.png beside "
                   "each reference).")
@click.option("--paper-rows", type=click.Path(exists=True, dir_okay=False), default=None, metavar="FILE",
              help="The paper's published rows to print beside the run's (YAML; docs/reproduce.md).")
@click.pass_context
def eval_cmd(ctx, pred, ref, metrics, refs_dir, linear, mask, background, out_prefix, lpips_backbone,
             lpips_weights, protocol, region, paper_rows):
    """Score PRED against REF.

    PRED and REF are two folders whose images are matched by relative path (the
    extension may differ), or PRED is a `zcomp composite` output folder whose jobs'
    report.json name their reference (or give --refs DIR).
    """
    from pathlib import Path

    from zcomp_cli.errors import UsageError
    from zcomp_cli.metrics.evaluate import (
        evaluate,
        is_composite_output,
        pair_composite_output,
        pair_folders,
        write_outputs,
    )

    pred_dir = Path(pred)
    unscored: dict[str, str] = {}
    if ref is not None and refs_dir is not None:
        raise UsageError("give either REF or --refs, not both")
    if ref is not None:
        pairs = pair_folders(pred_dir, ref, mask, background)
    elif is_composite_output(pred_dir):
        # Score the jobs that have a reference; list the others.
        pairs = pair_composite_output(pred_dir, refs_dir, mask, background, unscored=unscored)
    else:
        raise UsageError(f"{pred_dir} is not a composite output folder (no */report.json): give REF")

    setup = _protocol_setup(ctx, pairs, protocol, region, paper_rows, linear, metrics)
    if region == "object-crop":  # pairs whose object is unknown cannot be cropped: listed, not scored
        for p in [p for p in pairs if p.object_mask is None]:
            unscored[p.name] = "no object_mask.png beside the reference (needed by --region object-crop)"
        pairs = [p for p in pairs if p.object_mask is not None]
        if not pairs:
            raise UsageError("--region object-crop: no reference has an object_mask.png beside it "
                             "(zcomp import and make-benchmark write one)")
    result = evaluate(pairs, setup["metrics"], linear=linear, lpips_backbone=lpips_backbone,
                      lpips_weights=lpips_weights, region=region, encoding=setup["encoding"])
    result.unscored = {**unscored, **result.unscored}
    unscored = result.unscored
    result.protocol = setup["info"]
    prefix = Path(out_prefix) if out_prefix else pred_dir / "eval"
    csv_path, json_path = write_outputs(result, prefix)

    quiet = (ctx.obj or {}).get("quiet", False)
    for m, why in result.unavailable.items():
        click.secho(f"Warning: {m} unavailable: {why}", fg="yellow", err=True)
    for m, why in result.partial.items():
        click.secho(f"Warning: {m} left out for {why}", fg="yellow", err=True)
    if unscored:
        click.secho(f"Not scored ({len(unscored)}): " + "; ".join(f"{k}: {v}" for k, v in list(unscored.items())[:10])
                    + (" ..." if len(unscored) > 10 else ""), fg="yellow", err=True)
    if not quiet:
        _print_table(result, setup["rows"])
        if setup["info"].get("paper_rows_note"):
            click.echo(setup["info"]["paper_rows_note"])
    click.echo(f"Wrote {csv_path} and {json_path}")


def _protocol_setup(ctx, pairs, protocol, region, paper_rows, linear, metrics) -> dict:
    """The protocol of this run: its encoding and metrics, the dataset and the paper's
    rows to print (metrics/protocol.py, metrics/published.py)."""
    from click.core import ParameterSource

    from zcomp_cli.errors import UsageError
    from zcomp_cli.metrics import protocol as proto
    from zcomp_cli.metrics.published import dataset_of_pairs, load_rows, rows_for

    dataset, warnings = dataset_of_pairs(pairs)
    for w in warnings:
        click.secho(f"Warning: {w}", fg="yellow", err=True)
    if protocol is None:  # the paper's protocol on the paper's data, unless --linear asks for zcomp's
        protocol = "paper" if dataset is not None and not linear else "zcomp"
    if protocol == "paper" and linear:
        raise UsageError("--linear does not apply to --protocol paper (the paper scores gamma-encoded images)")
    if protocol == "paper" and ctx.get_parameter_source("metrics") == ParameterSource.DEFAULT:
        metrics = list(proto.PAPER_METRICS)
    given = load_rows(paper_rows) if paper_rows else None
    if given and given.get("dataset") and dataset and given["dataset"] != dataset:
        raise UsageError(f"--paper-rows {paper_rows} holds figures of {given['dataset']!r}; "
                         f"these references are {dataset!r} cases")
    # the published figures are only comparable under the paper's protocol (or when given)
    entry, rows = rows_for(dataset, region, given) if protocol == "paper" or given else (None, [])
    info = {"name": protocol, "encoding": "linear" if linear else proto.ENCODINGS[protocol], "region": region,
            "dataset": dataset, **({"warnings": warnings} if warnings else {})}
    if entry is not None:
        info["paper_source"] = entry["source"]
        info["paper_rows"] = rows
        if not rows:
            info["paper_rows_note"] = (
                f"Paper rows for {dataset} ({region}): none bundled with this zcomp (docs/reproduce.md, "
                f"'The paper's figures'); give --paper-rows FILE.")
        else:
            info["paper_rows_note"] = f"Paper rows: {entry['source']}."
    if protocol == "paper" and dataset is None and paper_rows is None:
        info["note"] = "the references are not from `zcomp import`: no published rows to compare with"
    return {"metrics": metrics, "encoding": proto.ENCODINGS[protocol], "info": info, "rows": rows}


def _print_table(result, paper_rows=()) -> None:
    from rich.console import Console
    from rich.table import Table

    from zcomp_cli.metrics.evaluate import HIGHER_IS_BETTER

    cols = [m for m in result.metrics]
    pr = result.protocol or {}
    enc = "linear" if result.linear else {"gamma2.2": "gamma 2.2"}.get(pr.get("encoding"), "sRGB")
    what = f"{pr.get('name', 'zcomp')} protocol, {enc}, {pr.get('region', 'full')}"
    if pr.get("dataset"):
        what += f", {pr['dataset']}"
    table = Table(title=f"zcomp eval ({what})")
    table.add_column("image")
    for m in cols:
        table.add_column(f"{m} {'↑' if HIGHER_IS_BETTER.get(m) else '↓'}", justify="right")

    def cell(vals, m):
        if m in result.unavailable:
            return "unavailable"
        v = vals[m]
        if v != v:  # NaN: not computable for this image
            return "n/a"
        return "inf" if v == float("inf") else f"{v:.4f}"

    for p, vals in zip(result.pairs, result.values):
        table.add_row(p.name, *(cell(vals, m) for m in cols))
    table.add_section()
    table.add_row("mean", *(cell(result.mean, m) for m in cols), style="bold")
    if paper_rows:
        from zcomp_cli.metrics.published import format_value

        table.add_section()
        for row in paper_rows:  # the paper's published figures for the same region, as printed there
            vals = row["metrics"]
            table.add_row(f"paper: {row['name']}", *(format_value(m, vals[m]) if m in vals else "-" for m in cols),
                          style="italic")
    Console(width=max(100, 14 * (len(cols) + 2))).print(table)
