"""What every stage shows and measures while it runs: a progress bar, the worker threads, peak memory."""

from __future__ import annotations

import resource
import sys
import threading
import time


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


class CompileMonitor:
    """Watches numba compile kernels during a stage: announces it once on stderr (a fresh install compiles the
    kernels on its first render, minutes on 2 cores; they are cached afterwards) and measures the seconds spent
    (the union of the compile intervals, nested and threaded ones counted once)."""

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.intervals: list[tuple[float, float]] = []
        self._open: dict = {}
        self._announced = False

    def __enter__(self):
        from numba.core import event

        monitor = self

        class _Listener(event.Listener):
            def on_start(self, ev):
                monitor._open.setdefault(threading.get_ident(), []).append(time.perf_counter())
                if not monitor._announced and not monitor.quiet:
                    monitor._announced = True
                    print("compiling numba kernels (once: they are cached for later runs)...", file=sys.stderr)

            def on_end(self, ev):
                stack = monitor._open.get(threading.get_ident())
                if stack:
                    monitor.intervals.append((stack.pop(), time.perf_counter()))

        self._listener = _Listener()
        event.register("numba:compile", self._listener)
        return self

    def __exit__(self, *exc):
        from numba.core import event

        event.unregister("numba:compile", self._listener)
        return False

    @property
    def seconds(self) -> float:
        total, end = 0.0, -1.0
        for a, b in sorted(self.intervals):
            if b > end:
                total += b - max(a, end)
                end = b
        return total
