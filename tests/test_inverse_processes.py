"""Worker processes for the fan screen and the auto candidates (xshells.inverse.processes)."""
import os
import signal
import threading
import time
from pathlib import Path

import pytest

from xshells.inverse.processes import RemoteProgress, in_processes


def _square(x):
    return x * x


def _wait_for_stop(path):
    progress = RemoteProgress("job")
    bar = progress.bar(1000, "waiting")
    for _ in range(1000):
        if progress.stopped():
            Path(path).write_text("stopped")  # as a candidate writes its design so far
            bar.close()
            return "stopped"
        bar.update(1)
        time.sleep(0.05)
    return "never asked"


def test_every_result_comes_back_with_its_jobs_index():
    assert dict(in_processes(_square, [(k,) for k in range(5)], 2)) == {k: k * k for k in range(5)}


def test_ctrl_c_asks_the_workers_to_stop_and_waits_for_them(tmp_path):
    paths = [tmp_path / "a", tmp_path / "b"]
    # a shell starts a background job with SIGINT ignored (CI may run so): Ctrl-C's own handler for this test
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(3.0, lambda: os.kill(os.getpid(), signal.SIGINT))  # Ctrl-C while they work
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            list(in_processes(_wait_for_stop, [(str(p),) for p in paths], 2, progress=True, stop_wait=30.0))
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert [p.read_text() for p in paths] == ["stopped", "stopped"]


def test_the_workers_read_3dm_files_with_the_commands_options():
    # a fork server's worker started with the reader's defaults, not --target-layer: the candidates of
    # `inverse site.3dm --target-layer roof` read every layer of the file
    from xshells.rhino.read import get_defaults, set_defaults

    set_defaults(target_layer="roof")
    try:
        assert [r["target_layer"] for _, r in in_processes(get_defaults, [()], 1)] == ["roof"]
    finally:
        set_defaults()



def _errors_and_a_division_by_zero():
    import numpy as np

    return np.geterr(), float((np.array([1.0]) / np.array([0.0]))[0])


@pytest.mark.parametrize("errors", ["ignore", "warn", "raise"])
def test_the_workers_handle_numpys_floating_point_errors_as_the_parent_does(errors):
    """The command runs under np.errstate(all="ignore"): its workers printed RuntimeWarnings all the same."""
    import numpy as np

    with np.errstate(all=errors):
        (_, got), = in_processes(_errors_and_a_division_by_zero if errors != "raise" else np.geterr, [()], 1)
    seen = got if errors == "raise" else got[0]
    assert set(seen.values()) == {errors}
    if errors != "raise":
        assert got[1] == np.inf
