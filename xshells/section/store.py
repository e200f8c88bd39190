"""Cross-section solves kept on disk, so that a profile is solved once per machine, not once per command.

The torsion constant's adaptive FEM refinement and its scikit-fem import
cost about 0.2 s of every ``xshells deploy`` (the manta ray's whole command
overhead was 1.2 s), for the same few profiles run after run. Their scalar
results are stored as small JSON files under the cache folder and read back
bit for bit (JSON writes floats by ``repr``, which round-trips exactly).

The folder is ``$XSHELLS_CACHE`` if set (``off``, ``0`` or empty: no cache),
else ``$XDG_CACHE_HOME/xshells``, else ``~/.cache/xshells``. An entry's name
hashes everything its result depends on: the profile's geometry, the solver
settings, the solver's own source files, and the installed scikit-fem,
triangle, NumPy and SciPy (each by the size and time of its ``__init__``), so
an upgrade or a change solves afresh. A folder that cannot be written, or an
entry that cannot be read, costs only the solve: the cache never fails a
command. Entries are written under a temporary name and renamed.
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
import tempfile
from pathlib import Path

FORMAT = 1  # bump when what an entry holds changes
ENV = "XSHELLS_CACHE"
_SOURCES = ("torsion.py", "mesh.py", "profiles.py", "properties.py")  # what the stored results come from
_OFF = ("", "0", "off", "none", "false", "no")


def cache_dir() -> Path | None:
    """The cache folder, or None when ``$XSHELLS_CACHE`` turns the cache off."""
    value = os.environ.get(ENV)
    if value is not None:
        return None if value.strip().lower() in _OFF else Path(value).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "xshells"


@functools.lru_cache(maxsize=1)
def _versions() -> tuple:
    """What the stored results depend on besides their inputs: the solver's source files, and the
    installed scikit-fem, triangle, NumPy and SciPy, each by its ``__init__``'s size and modification
    time (found without importing it; ``importlib.metadata`` took 80 ms here, a third of what the cache saves)."""
    from importlib.util import find_spec

    h = hashlib.sha256()
    for name in _SOURCES:
        try:
            h.update((Path(__file__).parent / name).read_bytes())
        except OSError:
            h.update(name.encode())
    out = [("source", h.hexdigest())]
    for name in ("skfem", "triangle", "numpy", "scipy"):
        try:
            spec = find_spec(name)
            st = os.stat(spec.origin)
            out.append((name, spec.origin, st.st_size, st.st_mtime_ns))
        except (ImportError, ValueError, AttributeError, TypeError, OSError):
            out.append((name, None))
    return tuple(out)


def _entry(kind: str, parts: tuple) -> Path | None:
    folder = cache_dir()
    if folder is None:
        return None
    h = hashlib.sha256(repr((FORMAT, kind, _versions())).encode())
    for part in parts:
        h.update(part if isinstance(part, bytes) else repr(part).encode())
    return folder / "sections" / f"{kind}-{h.hexdigest()[:40]}.json"


def load(kind: str, parts: tuple) -> dict | None:
    """The stored result of ``kind`` for ``parts`` (bytes or values with an exact ``repr``), or None."""
    path = _entry(kind, parts)
    if path is None:
        return None
    try:
        with open(path, encoding="utf-8") as fh:
            value = json.load(fh)
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def save(kind: str, parts: tuple, value: dict) -> None:
    """Store ``value`` (JSON-ready) as the result of ``kind`` for ``parts``; silently skipped where it cannot be."""
    path = _entry(kind, parts)
    if path is None:
        return
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(value, fh)
        os.replace(tmp, path)
        tmp = None
    except OSError:
        pass
    finally:
        if tmp is not None:
            try:
                os.remove(tmp)
            except OSError:
                pass


def relative_change(history) -> float:
    """|J_k − J_{k−1}| / J_k of the last two levels of a refinement ``history`` of (n_dofs, J); inf with one level."""
    if len(history) < 2:
        return float("inf")
    return abs(history[-1][1] - history[-2][1]) / history[-1][1]
