"""Where the tests find example data: bundled with the package, and the shared
ElasticRods data beside the repository (present for developers and CI)."""
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "elasticrods"
EXAMPLES = REPO / "xshells" / "data" / "examples"
needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared ElasticRods data not found at {DATA}")
