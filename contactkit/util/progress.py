"""Progress bars on stderr for long work, one factory for every command."""

from __future__ import annotations

from collections.abc import Callable

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TaskID,
    TextColumn,
    TimeRemainingColumn,
)

ProgressCallback = Callable[[int, int], None]
"""``(done, total)``: how many items of how many are finished."""
LabelledProgress = Callable[[str, int, int], None]
"""``(label, done, total)``: one bar per label."""

err_console = Console(stderr=True)


def progress_bar(label: str = "", *, disable: bool = False) -> Progress:
    """Return a rich progress bar on stderr: ``label``, the task's description, done/total,
    time left. Use it as a context manager."""
    prefix = f"[bold]{label}[/] " if label else ""
    return Progress(TextColumn(prefix + "[bold]{task.description}[/]"), BarColumn(),
                    MofNCompleteColumn(), TimeRemainingColumn(), console=err_console,
                    disable=disable)


def bar_callback(bar: Progress, description: str = "") -> ProgressCallback:
    """Return a ``(done, total)`` callback that drives one new task of ``bar``."""
    task = bar.add_task(description, total=None)

    def update(done: int, total: int) -> None:
        bar.update(task, completed=done, total=total)

    return update


def labelled_progress(bar: Progress) -> LabelledProgress:
    """Return a callback ``(label, done, total)`` that keeps one task of ``bar`` per label."""
    tasks: dict[str, TaskID] = {}

    def progress(label: str, done: int, total: int) -> None:
        if label not in tasks:
            tasks[label] = bar.add_task(label, total=total)
        bar.update(tasks[label], completed=done, total=total, description=label)

    return progress
