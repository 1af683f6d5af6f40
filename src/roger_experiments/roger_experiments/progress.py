"""Progress of long commands (run, compare, train, bench): a rich bar on a terminal, plain
lines elsewhere (logs, CI, a pipe), nothing when quiet.

Bars may nest (compare's runs, each run's cycles): they share one live display, an inner
bar leaves its final line above the others when it closes. The final line of a bar is
what its owner passes to :meth:`ProgressBar.close`, so it can be the numbers the run wrote
(metrics.json) rather than the last live update.
"""
from __future__ import annotations

import sys
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any, TextIO

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeElapsedColumn,
)

#: Without a terminal: a line each time another tenth of the total is done.
PLAIN_STEP = 0.1
#: Without a terminal, totals up to this many steps print every step.
PLAIN_EVERY_STEP = 20
#: Without a terminal, a line at least this often (wall seconds) while steps are done: a
#: run with a large budget (--until-complete) may end long before its first tenth.
PLAIN_EVERY_S = 30.0


class _Live:
    """The one rich live display the open bars share (rich allows one at a time)."""

    progress: Progress | None = None
    users = 0

    @classmethod
    def add(cls, console: Console, description: str, total: int, unit: str) -> TaskID:
        if cls.progress is None:
            cls.progress = Progress(
                TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                TextColumn("{task.fields[unit]}"), TimeElapsedColumn(),
                TextColumn("{task.fields[info]}"), console=console, transient=False)
            cls.progress.start()
        cls.users += 1
        return cls.progress.add_task(description, total=total, unit=unit, info="")

    @classmethod
    def finish(cls, task: TaskID, final: str) -> None:
        live = cls.progress
        assert live is not None
        cls.users -= 1
        if cls.users > 0:
            # An inner bar: its final line stays above the bars still running.
            live.remove_task(task)
            live.console.print(final, highlight=False, markup=False)
            return
        live.stop()  # the last bar stays on screen with its final numbers
        cls.progress = None


class ProgressBar:
    """Progress of ``total`` steps of one command.

    Args:
        total: Steps expected (at least 1 is shown).
        description: What runs (e.g. "run inspection, qlearning").
        unit: What a step is ("cycles", "runs").
        enabled: False shows nothing (``--quiet``).
        stream: Where it goes (standard error by default, so results on standard output
            stay clean for pipes).
        clock: Wall seconds (for the plain lines' pace).
    """

    def __init__(self, total: int, description: str, unit: str = "cycles", *,
                 enabled: bool = True, stream: TextIO | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.total, self.description, self.unit = max(1, int(total)), description, unit
        self.enabled = enabled
        self.stream = stream if stream is not None else sys.stderr
        self.done, self.info = 0, ""
        self._closed = not enabled
        self._task: TaskID | None = None
        self._printed: tuple[int, str] | None = None
        self._bucket = -1
        self._clock = clock
        self._printed_at = clock()
        if enabled:
            console = Console(file=self.stream)
            if console.is_terminal:
                self._task = _Live.add(console, description, self.total, unit)

    @property
    def live(self) -> bool:
        """True when shown as a rich bar (a terminal), False for plain lines or quiet."""
        return self._task is not None

    def line(self) -> str:
        """The progress as one plain line."""
        info = f" {self.info}" if self.info else ""
        return f"  {self.description}: {self.done}/{self.total} {self.unit}{info}"

    def update(self, done: int, info: str = "") -> None:
        """Show ``done`` of ``total`` steps and ``info`` (e.g. the run's counters)."""
        if self._closed:
            return
        self.done, self.info = int(done), info
        if self._task is not None:
            assert _Live.progress is not None
            _Live.progress.update(self._task, completed=min(self.done, self.total), info=info)
            return
        bucket = int(min(1.0, self.done / self.total) / PLAIN_STEP)
        new_step = self._printed is None or self._printed[0] != self.done
        every = new_step and (self.total <= PLAIN_EVERY_STEP
                              or self._clock() - self._printed_at >= PLAIN_EVERY_S)
        if bucket > self._bucket or every:
            self._bucket = max(self._bucket, bucket)
            self._print()

    def _print(self) -> None:
        if self._printed == (self.done, self.info):
            return
        self._printed = (self.done, self.info)
        self._printed_at = self._clock()
        self.stream.write(self.line() + "\n")
        self.stream.flush()

    def close(self, done: int | None = None, info: str | None = None) -> None:
        """End the bar with its final numbers (the last update's unless given)."""
        if self._closed:
            return
        if done is not None:
            self.done = int(done)
        if info is not None:
            self.info = info
        self._closed = True
        if self._task is not None:
            assert _Live.progress is not None
            _Live.progress.update(self._task, completed=min(self.done, self.total),
                                  info=self.info)
            _Live.finish(self._task, self.line())
            self._task = None
        else:
            self._print()

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def counters_info(counters: dict[str, Any]) -> str:
    """The counters a run's bar shows, from live counters or metrics.json alike."""
    return (f"shifts {int(counters.get('attention_shifts', 0))} "
            f"new {int(counters.get('new_objects', 0))} "
            f"ids {int(counters.get('positive_identifications', 0))}")


__all__ = ["ProgressBar", "counters_info"]
