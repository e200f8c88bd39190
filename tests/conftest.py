"""Session-wide settings for the test suite."""
import os
import tempfile

import pytest

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
