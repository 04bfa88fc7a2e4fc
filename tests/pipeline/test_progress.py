"""What the stages report while they run: compile time."""

from numba import njit

from pbvol_cli.pipeline.progress import CompileMonitor


def test_the_compile_monitor_announces_compiling_once_and_measures_it(capsys):
    @njit
    def twice(x):
        return 2 * x

    with CompileMonitor() as monitor:
        twice(1)
        twice(1.5)  # a second signature: a second compile, announced once
        twice(2)  # compiled already
    assert monitor.seconds > 0
    assert capsys.readouterr().err.count("compiling numba kernels") == 1
    with CompileMonitor(quiet=True) as quiet:
        twice(3)
    assert quiet.seconds == 0 and capsys.readouterr().err == ""


def test_progress_in_a_log_is_plain_lines_at_an_interval():
    """stderr that is not a terminal (a CI log) gets a plain line every interval and one at the end, not a bar."""
    import io

    from pbvol_cli.pipeline.progress import PlainProgress, progress_bar

    log = io.StringIO()  # not a terminal
    prog, update = progress_bar(False, "volpath 8x8 4 spp", "paths", stream=log)
    assert isinstance(prog, PlainProgress)
    now = [0.0]
    plain = PlainProgress("pbl", "pixel samples", log, interval=10.0, clock=lambda: now[0])
    with plain:
        for t, done in ((1.0, 10), (5.0, 50), (11.0, 110), (12.0, 120), (25.0, 250)):
            now[0] = t
            plain.update(done, 400)
    lines = log.getvalue().splitlines()
    # the line at the end is not repeated when the last one said the same
    assert lines == ["pbl: 110/400 pixel samples (28 %), 11 s elapsed",
                     "pbl: 250/400 pixel samples (62 %), 25 s elapsed"], lines
    quiet = io.StringIO()
    with PlainProgress("pbl", "x", quiet, quiet=True) as q:
        q.update(1, 2)
    assert quiet.getvalue() == ""
