"""Session-wide settings for the test suite."""
import os
import tempfile

# One BLAS thread per test process, as `xshells` itself runs (xshells/cli.py), set before anything imports
# NumPy. The suite runs on two pytest-xdist workers (pyproject), one per core: with OpenBLAS's default two
# threads each solve competed with the other worker, and even alone a 606-segment sparsify test took
# 78 s on two threads against 70 s on one.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import pytest  # noqa: E402

# The cross-section cache (xshells.section.store) goes to a folder of this run's own, so that the suite
# neither reads a developer's cache nor leaves entries in the home folder (child processes inherit it).
os.environ["XSHELLS_CACHE"] = tempfile.mkdtemp(prefix="xshells-test-cache-")


@pytest.fixture
def reset_3dm_options():
    """The command line's .3dm options (--layer, --sample, --target-layer) are process-wide: back to none after
    a test that runs a command with them."""
    yield
    from xshells.rhino.read import set_defaults

    set_defaults()
