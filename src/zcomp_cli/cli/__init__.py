"""The ``zcomp`` command group.

One module per command (``zcomp_cli.cli.<command>``), loaded lazily so that
``zcomp --help`` never imports numpy, torch or bpy. Typed ``ZcompError`` exceptions
become a one-line message and an exit code (1: failed run, 2: usage); a Python
traceback is shown only with ``-v``.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import sys

import click

from zcomp_cli import __version__

from zcomp_cli.interrupts import Interrupted  # noqa: F401 - re-exported

EXIT_INTERRUPTED = 130  # 128 + SIGINT


def exit_code_of(exc: KeyboardInterrupt) -> int:
    """128 + the signal number, the shell's convention (130 for Ctrl-C)."""
    return 128 + int(getattr(exc, "signum", 2))


@contextlib.contextmanager
def signals_as_interrupts():
    """While a command runs: SIGINT, SIGTERM and SIGHUP raise ``Interrupted`` (a
    KeyboardInterrupt), at once or at the end of a step that must run whole
    (``interrupts.deferred``); a repeated one is ignored so that the clean-up it
    triggered finishes. A signal the parent told zcomp to ignore (``nohup`` ignores
    SIGHUP) stays ignored. The previous handlers come back afterwards. Main thread only
    (elsewhere, e.g. in a Ray worker, nothing changes)."""
    import signal
    import threading

    from zcomp_cli.interrupts import interrupt

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    seen = []

    def handler(signum, frame):
        if seen:
            return
        seen.append(signum)
        interrupt(signum)

    old = {}
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        try:
            if signal.getsignal(sig) is signal.SIG_IGN:  # `nohup zcomp ...`: a hang-up is ignored, as asked
                continue
            old[sig] = signal.signal(sig, handler)
        except (ValueError, OSError):  # pragma: no cover - not the main interpreter
            pass
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)

# command name -> (module, attribute, one-line help shown by `zcomp --help`)
_COMMANDS: dict[str, tuple[str, str, str]] = {
    "render-intrinsics": (
        "zcomp_cli.cli.render_intrinsics",
        "render_intrinsics",
        "Render object intrinsics (depth, normals, albedo, mask, footprint) with Blender.",
    ),
    "composite": (
        "zcomp_cli.cli.composite",
        "composite",
        "Composite objects into scenes for every job of a manifest.",
    ),
    "eval": ("zcomp_cli.cli.eval", "eval_cmd", "Score composites against references."),
    "make-benchmark": (
        "zcomp_cli.cli.make_benchmark",
        "make_benchmark",
        "Build a benchmark with physically rendered ground truth.",
    ),
    "estimate": (
        "zcomp_cli.cli.estimate",
        "estimate",
        "Estimate missing background intrinsics of a manifest's scenes.",
    ),
    "preview-light": ("zcomp_cli.cli.preview_light", "preview_light",
                      "Render each scene's light on three balls (grey, silver, mirror) before a batch."),
    "train": ("zcomp_cli.cli.train", "train", "Train the ZeroComp ControlNet."),
    "status": ("zcomp_cli.cli.status", "status",
               "Merge an output folder's runs and shards: done, failed, missing jobs."),
    "import": ("zcomp_cli.cli.import_group", "import_group",
               "Import the ZeroComp or SpotLight evaluation set as a manifest."),
    "report": ("zcomp_cli.cli.report", "report",
               "Write one HTML page for an output folder: thumbnails, status, light, metrics."),
}


class LazyGroup(click.Group):
    """A click group whose sub-commands are imported only when invoked."""

    def list_commands(self, ctx):
        return [n for n in _COMMANDS if _available(n)]

    def get_command(self, ctx, name):
        if name not in _COMMANDS or not _available(name):
            return None
        module, attr, _ = _COMMANDS[name]
        return getattr(importlib.import_module(module), attr)

    def invoke(self, ctx):
        # Typed errors become a clean message and exit code here (not only in main()),
        # so that click's test runner and `python -m zcomp_cli` behave the same.
        from zcomp_cli.errors import ZcompError

        try:
            with signals_as_interrupts():
                return super().invoke(ctx)
        except ZcompError as exc:
            if (ctx.obj or {}).get("verbose"):
                import traceback

                traceback.print_exc()
            click.secho(f"Error: {exc}", fg="red", err=True)
            ctx.exit(exc.exit_code)
        except KeyboardInterrupt as exc:
            # Ctrl-C, SIGTERM, SIGHUP: the shell convention 128 + the signal, not
            # click's "Aborted!" and 1 (a command that said what is on disk has said it)
            if not getattr(exc, "zcomp_reported", False):
                click.echo("\nInterrupted.", err=True)
            ctx.exit(exit_code_of(exc))

    def format_commands(self, ctx, formatter):
        # Short help from the table: listing commands must not import them.
        rows = [(n, _COMMANDS[n][2]) for n in self.list_commands(ctx)]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


def _available(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(_COMMANDS[name][0]) is not None


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "--version", prog_name="zcomp")
@click.option("-v", "--verbose", count=True, help="More output; -v also shows tracebacks.")
@click.option("-q", "--quiet", is_flag=True, help="Only errors and the final summary.")
@click.pass_context
def cli(ctx, verbose: int, quiet: bool):
    """zcomp: composite 3D objects into photographs with realistic shading and shadows."""
    from zcomp_cli.errors import TRACEBACK_LOGGER

    level = logging.WARNING if quiet else (logging.DEBUG if verbose > 1 else logging.INFO)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    # -v shows the tracebacks of the errors zcomp catches to go on (a job's internal error)
    logging.getLogger(TRACEBACK_LOGGER).setLevel(logging.DEBUG if verbose else logging.NOTSET)
    ctx.ensure_object(dict)
    ctx.obj["verbose"] = verbose
    ctx.obj["quiet"] = quiet


def _ignore_signals_from_now() -> None:
    """The command is over (its outputs and summary are written or it has failed): a
    SIGINT, SIGTERM or SIGHUP during the interpreter's tear-down (a fraction of a
    second; Ray's shutdown) is ignored and the process exits with the command's own
    code. (No Python handler runs during finalization, where the default action would
    kill the process with the signal, as if the finished run had been interrupted; a
    SIGINT there raised a KeyboardInterrupt nothing caught, and the process died of it
    with its outputs written: the signal fuzz's "-2 with outputs". An ignored signal
    stays ignored there.)"""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        with contextlib.suppress(ValueError, OSError):
            signal.signal(sig, signal.SIG_IGN)


def main(argv: list[str] | None = None) -> None:
    """Entry point: run the group, turning typed errors into exit codes."""
    from zcomp_cli.errors import ZcompError

    verbose = any(a in ("-v", "-vv", "--verbose") for a in (argv or sys.argv[1:]))
    try:
        try:
            with signals_as_interrupts():  # from the start: option callbacks write probe files too
                rv = cli.main(args=argv, prog_name="zcomp", standalone_mode=False)
        finally:
            if argv is None:  # the `zcomp` process itself (not a caller's process): it ends now
                _ignore_signals_from_now()
    except ZcompError as exc:
        if verbose:
            import traceback

            traceback.print_exc()
        click.secho(f"Error: {exc}", fg="red", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.Abort as exc:
        if isinstance(exc.__cause__, KeyboardInterrupt):
            click.echo("Interrupted.", err=True)
            sys.exit(exit_code_of(exc.__cause__))
        click.echo("Aborted.", err=True)
        sys.exit(1)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except KeyboardInterrupt as exc:
        click.echo("Interrupted.", err=True)
        sys.exit(exit_code_of(exc))
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    # With standalone_mode=False, click returns ctx.exit()'s code instead of exiting.
    sys.exit(rv if isinstance(rv, int) else 0)
