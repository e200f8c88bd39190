"""Session-wide settings for the test suite."""
import os
import tempfile

# The cross-section cache (xshells.section.store) goes to a folder of this run's own, so that the suite
# neither reads a developer's cache nor leaves entries in the home folder (child processes inherit it).
os.environ["XSHELLS_CACHE"] = tempfile.mkdtemp(prefix="xshells-test-cache-")
