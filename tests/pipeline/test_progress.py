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
