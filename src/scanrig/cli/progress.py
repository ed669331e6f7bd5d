"""Progress of long commands: bars on a terminal, plain lines in a log.

A command reports ``progress(stage, done, total)`` (``total`` None while unknown). On a terminal
each stage gets a rich bar. When stdout is not a terminal (a log file, CI, a job queue) a bar shows
nothing useful, so a plain line is printed when a stage starts, at least every ``interval_s``
seconds while it runs, and when it ends: stage, done / total, rate and time left.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import typer

#: Seconds between two plain progress lines of one stage.
PLAIN_INTERVAL_S = 5.0


@contextmanager
def stage_progress(console=None, interval_s: float = PLAIN_INTERVAL_S,
                   plain: bool | None = None) -> Iterator[Callable[[str, int, int | None], None]]:
    """A ``progress(stage, done, total)`` callback for the duration of the ``with`` block.

    Parameters
    ----------
    console : rich.console.Console, optional
        Where the bars go on a terminal.
    interval_s : float
        Seconds between plain lines of one stage.
    plain : bool, optional
        Plain lines (default: when stdout is not a terminal).
    """
    if plain is None:
        plain = not sys.stdout.isatty()
    if plain:
        lines = _PlainLines(interval_s)
        try:
            yield lines.update
        finally:
            lines.close()
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(TextColumn("{task.description:<22}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=console) as bar:
        tasks: dict[str, int] = {}

        def update(stage: str, done: int, total: int | None) -> None:
            if stage not in tasks:
                _finish(bar)  # a stage is over once the next one reports
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done, total=total)

        yield update
        _finish(bar)


def _finish(bar) -> None:
    """Show every bar of ``bar`` (a rich Progress) as complete, with its count."""
    for task in bar.tasks:
        final = task.total if task.total is not None else max(task.completed, 1)
        bar.update(task.id, total=final, completed=final)


class _PlainLines:
    """Plain progress lines, one stage at a time (see :func:`stage_progress`)."""

    def __init__(self, interval_s: float):
        self.interval_s = interval_s
        self.stage: str | None = None
        # stages run one after the other: one starts when the one before ended (its first report
        # may come after its first item)
        self.started = self.last_line = time.monotonic()
        self.done, self.total = 0, None

    def update(self, stage: str, done: int, total: int | None) -> None:
        now = time.monotonic()
        if stage != self.stage:
            self.close()
            self.stage, self.last_line = stage, now
            typer.echo(f"{stage}: started" + ("" if total is None else f", {total} to do"))
        self.done, self.total = done, total
        if total is not None and done >= total:
            self.close()
        elif now - self.last_line >= self.interval_s:
            self.last_line = now
            typer.echo(f"{stage}: {self._counts(now)}")

    def close(self) -> None:
        """End the current stage with its line."""
        if self.stage is not None:
            now = time.monotonic()
            counts = ("" if self.total is None and not self.done
                      else f" {self.done}" + ("" if self.total is None else f"/{self.total}"))
            typer.echo(f"{self.stage}: done{',' if counts else ''}{counts} in {now - self.started:.1f} s")
            self.stage, self.started = None, now

    def _counts(self, now: float) -> str:
        elapsed = max(now - self.started, 1e-9)
        rate = self.done / elapsed
        text = f"{self.done}" + ("" if self.total is None else f"/{self.total}") + f", {rate:.2f}/s"
        if self.total is not None and rate > 0:
            text += f", about {(self.total - self.done) / rate:.0f} s left"
        return text
