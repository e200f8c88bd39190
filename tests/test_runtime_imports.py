"""JAX is a test oracle only: the runtime never imports it (it is in the ``test`` extra, not a dependency)."""
import subprocess
import sys

from data_paths import EXAMPLES, REPO

SCRIPT = r"""
import sys
import xshells.deploy.run
assert not [m for m in sys.modules if m == "jax" or m.startswith(("jax.", "jaxlib"))], "import xshells.deploy.run loaded jax"
from xshells.cli import main
rc = main(["deploy", sys.argv[1], "--out", sys.argv[2], "--steps", "3", "--no-progress"])
assert rc == 0, rc
loaded = sorted(m for m in sys.modules if m == "jax" or m.startswith(("jax.", "jaxlib")))
assert not loaded, loaded[:5]
print("no jax")
"""


def test_a_full_deploy_imports_no_jax(tmp_path):
    p = subprocess.run([sys.executable, "-c", SCRIPT, str(EXAMPLES / "quad.obj"), str(tmp_path / "out")], cwd=REPO,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "no jax" in p.stdout


def test_jax_is_not_a_runtime_dependency():
    import tomllib

    meta = tomllib.loads((REPO / "pyproject.toml").read_text())
    runtime = " ".join(meta["project"]["dependencies"]).lower()
    assert "jax" not in runtime
    assert any(d.lower().startswith("jax") for d in meta["project"]["optional-dependencies"]["test"])
