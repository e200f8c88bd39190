"""JAX configuration shared by every module: CPU, float64, persistent cache.

The persistent compilation cache makes a second process start in well under
the cold compile time; its folder can be moved with ``XSHELLS_JAX_CACHE``.
"""
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

_cache = os.environ.get(
    "XSHELLS_JAX_CACHE",
    os.path.join(os.path.expanduser("~"), ".cache", "xshells", "jax"),
)
try:
    os.makedirs(_cache, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", _cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
except OSError:  # read-only home: run without the persistent cache
    pass
