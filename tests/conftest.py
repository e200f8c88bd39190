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


# The slowest files are handed out first. pytest-xdist's loadfile scheduling gives files to the workers in
# collection order, so a long file collected late ran alone at the end: on 2026-12-06 the suite took 18 min 29 s
# while Darth Vader's realizable design (test_inverse_targets.py, 306 s) ran alone over its last minutes.
SLOWEST_FIRST = ("test_inverse_targets.py", "test_inverse_run.py", "test_actuation_selection.py")


def pytest_collection_modifyitems(session, config, items):
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(os.path.basename(str(item.path)), len(SLOWEST_FIRST)))  # stable


@pytest.fixture
def reset_3dm_options():
    """The command line's .3dm options (--layer, --sample, --target-layer) are process-wide: back to none after
    a test that runs a command with them."""
    yield
    from xshells.rhino.read import set_defaults

    set_defaults()
