"""What every stage shows and measures while it runs: a progress bar, the worker threads, peak memory."""

from __future__ import annotations

import resource


def progress_bar(quiet: bool, label: str, unit: str = "paths"):
    """A rich progress bar on stderr with elapsed time and ETA. Returns (context manager, update(done, total))."""
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)

    prog = Progress(
        TextColumn(label), BarColumn(), MofNCompleteColumn(), TextColumn(unit),
        TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
        console=Console(stderr=True), disable=quiet, transient=False,
    )
    task = prog.add_task(label, total=None)

    def update(done, total):
        prog.update(task, completed=done, total=total)

    return prog, update


def set_threads(threads: int | None) -> int:
    """Use this many worker threads (None: all numba has), at most numba's maximum. Returns the count."""
    import numba

    n = threads or numba.config.NUMBA_NUM_THREADS
    n = max(1, min(int(n), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(n)
    return n


def peak_memory_mb() -> float:
    """Peak resident memory of this process so far (MiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
