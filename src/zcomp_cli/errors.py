"""Typed errors. The CLI turns every ``ZcompError`` into a clean message and exit code.

Exit codes: 1 for a failed run (bad input data, a render that failed, missing weights),
2 for usage errors (bad flags, an invalid manifest).
"""

from __future__ import annotations


class ZcompError(Exception):
    """Base class of every error zcomp reports to a user (no traceback unless -v)."""

    exit_code = 1

    def __init__(self, message: str, *, where: str | None = None):
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)


class UsageError(ZcompError):
    """Wrong flags or arguments."""

    exit_code = 2


class ManifestError(ZcompError):
    """A manifest (jobs.yaml, objects.yaml, train config) is invalid.

    ``problems`` holds every problem found, each already naming its location.
    """

    exit_code = 2

    def __init__(self, problems: list[str] | str, *, source: str | None = None):
        if isinstance(problems, str):
            problems = [problems]
        self.problems = list(problems)
        self.source = source
        head = f"{source}: " if source else ""
        n = len(self.problems)
        if n == 1:
            first = self.problems[0]
            base = source.replace("\\", "/").rsplit("/", 1)[-1] if source else None
            # "jobs.yaml:12: ..." already names the file: say its full path once.
            msg = f"{source}{first[len(base):]}" if base and first.startswith(base + ":") else f"{head}{first}"
        else:
            msg = f"{head}{n} problems:\n" + "\n".join(f"  - {p}" for p in self.problems)
        Exception.__init__(self, msg)
        self.where = source


class InputError(ZcompError):
    """An input file is missing, unreadable, or holds data of the wrong shape or values."""


class OutputError(ZcompError):
    """An output cannot be written (disk full, no permission, a path that is not a folder)."""


class GeometryError(ZcompError):
    """Degenerate geometry: object behind the camera, outside the frame, zero size..."""


class RenderError(ZcompError):
    """A renderer (Blender, physical, zerocomp) failed."""


class WeightsError(ZcompError):
    """Model weights are missing or do not match what the code expects."""


class NumericalError(ZcompError):
    """A computation produced non-finite values where it must not (e.g. fp16 overflow)."""


# The logger of tracebacks zcomp catches to go on (a job's internal error): the CLI
# lets it through from -v on (``cli.cli``), as it shows the tracebacks of errors it stops
# on; without -v it is silent whatever the log level.
TRACEBACK_LOGGER = "zcomp_cli.tracebacks"


def log_traceback(what: str, exc: BaseException) -> None:
    """Log ``exc``'s traceback, headed by ``what``, on ``TRACEBACK_LOGGER``."""
    import logging
    import traceback

    logging.getLogger(TRACEBACK_LOGGER).debug("%s:\n%s", what, "".join(traceback.format_exception(exc)))
