"""What every stage shows and measures while it runs: progress (a bar, or plain lines in a log), the worker
threads, peak memory, compile time."""

from __future__ import annotations

import resource
import sys
import threading
import time


PLAIN_INTERVAL_S = 10.0  # seconds between the plain progress lines of a non-terminal stderr (a CI log)


def progress_bar(quiet: bool, label: str, unit: str = "paths", stream=None):
    """Progress on stderr (or stream): a rich bar with elapsed time and ETA on a terminal; elsewhere (a CI log) a
    plain line every PLAIN_INTERVAL_S seconds and one at the end. Returns (context manager, update(done, total))."""
    stream = sys.stderr if stream is None else stream
    if quiet or not stream.isatty():
        plain = PlainProgress(label, unit, stream, quiet)
        return plain, plain.update
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                               TimeRemainingColumn)

    prog = Progress(
        TextColumn(label), BarColumn(), MofNCompleteColumn(), TextColumn(unit),
        TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
        console=Console(file=stream), transient=False,
    )
    task = prog.add_task(label, total=None)

    def update(done, total):
        prog.update(task, completed=done, total=total)

    return prog, update


class PlainProgress:
    """Progress as plain lines ("label: done/total unit (p %), t s elapsed"), at most one per interval and one at
    the end: readable in a log file, where a live bar is noise."""

    def __init__(self, label: str, unit: str, stream, quiet: bool = False, interval: float = PLAIN_INTERVAL_S,
                 clock=time.monotonic):
        self.label, self.unit, self.stream, self.quiet = label, unit, stream, quiet
        self.interval, self.clock = interval, clock
        self.done, self.total = 0, None
        self.printed = None  # the (done, total) of the last line
        self.start = self.last = clock()

    def __enter__(self):
        self.start = self.last = self.clock()
        return self

    def update(self, done, total):
        self.done, self.total = done, total
        if self.clock() - self.last >= self.interval:
            self._line()

    def _line(self):
        self.last = self.clock()
        if self.quiet or self.printed == (self.done, self.total):
            return
        self.printed = (self.done, self.total)
        share = f" ({100.0 * self.done / self.total:.0f} %)" if self.total else ""
        of = f"/{self.total}" if self.total is not None else ""
        print(f"{self.label}: {self.done}{of} {self.unit}{share}, {self.last - self.start:.0f} s elapsed",
              file=self.stream, flush=True)

    def __exit__(self, *exc):
        if exc[0] is None:
            self._line()
        return False


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


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux MemAvailable), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


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
