"""A rich progress display with one bar per pipeline stage (objects, jobs)."""

from __future__ import annotations


class StageProgress:
    """Context manager; ``update(stage, done, total, label)`` drives one bar per stage."""

    def __init__(self, disable: bool = False):
        self.disable = disable
        self._progress = None
        self._tasks: dict[str, int] = {}

    def __enter__(self):
        if not self.disable:
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                       TimeElapsedColumn, TimeRemainingColumn)

            self._progress = Progress(
                TextColumn("[bold]{task.fields[stage]:<8}"), BarColumn(), MofNCompleteColumn(),
                TimeElapsedColumn(), TimeRemainingColumn(), TextColumn("{task.fields[label]}"),
                console=Console(stderr=True), transient=False,
            )
            self._progress.__enter__()
        return self

    def update(self, stage: str, done: int, total: int, label: str = "") -> None:
        if self._progress is None:
            return
        if stage not in self._tasks:
            self._tasks[stage] = self._progress.add_task("", total=total, stage=stage, label=label)
        self._progress.update(self._tasks[stage], completed=done, total=total, label=label)

    def warn(self, text: str) -> None:
        """A warning on stderr, printed above the bars when they are shown (a plain
        line otherwise: warnings are not silenced by --quiet)."""
        if self._progress is not None:
            self._progress.console.print(f"[yellow]Warning:[/] {text}", highlight=False, soft_wrap=True)
        else:
            import click

            click.secho(f"Warning: {text}", fg="yellow", err=True)

    def __exit__(self, *exc):
        if self._progress is not None:
            self._progress.__exit__(*exc)
        return False
