"""Writing designs and centerlines as OBJ line graphs.

Files are written to a temporary file in the destination folder and moved
into place with :func:`os.replace`, so a reader never sees a half-written
file and an interrupted write leaves the old file intact.
"""
from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Iterable, Sequence

import numpy as np

from .design import Design

__all__ = ["atomic_write_text", "output_target", "replace_with", "write_design_obj", "write_polylines_obj"]


def _read_umask() -> int:
    """The process's umask: from /proc where Linux shows it, else by setting and restoring it (the only
    portable way to read it, but another thread creating a file meanwhile would get 022)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


# mkstemp makes files only their owner can read (0600); a finished output gets the mode that open() would
# give it under the process's umask
_UMASK = _read_umask()


def output_target(path: str | os.PathLike) -> str:
    """The file that writing ``path`` replaces: a symbolic link's target (written through, as ``open``
    would; replacing the link itself lost it), else ``path`` itself.

    Raises
    ------
    InputError
        ``path`` exists and is not a regular file (a device such as ``/dev/null``, a folder): renaming a
        finished file onto it would replace the device node.
    """
    from ..errors import InputError

    path = os.fspath(path)
    if not path:
        raise InputError("the output path is empty")
    target = os.path.realpath(path)
    if os.path.exists(target) and not os.path.isfile(target):
        what = "a folder" if os.path.isdir(target) else "not a regular file"
        raise InputError(f"{path}: {what}: an output must be a file (give a file name)")
    return target


def replace_with(tmp: str, target: str) -> None:
    """Move the finished temporary file ``tmp`` onto ``target`` (from :func:`output_target`), with the mode a
    newly opened file would have."""
    os.chmod(tmp, 0o666 & ~_UMASK)
    os.replace(tmp, target)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file + ``os.replace``): never a half-written file."""
    target = output_target(path)
    folder = os.path.dirname(target)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=os.path.basename(target), dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        replace_with(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def prepare_output_dir(path: str | os.PathLike) -> str:
    """Create the output folder ``path`` and check that files can be written there, before any work starts.

    Raises
    ------
    InputError
        One line naming the folder and why it cannot be used.
    """
    from ..errors import InputError

    path = os.fspath(path)
    if not path.strip():
        raise InputError("--out is empty: give the output folder")
    if os.path.exists(path) and not os.path.isdir(path):
        raise InputError(f"--out {path}: exists and is not a folder")
    # the first folder on the way that does not exist yet: removed again after the probe, so that a
    # command refused later for its input leaves nothing behind (each command creates its folder itself)
    first_new, head = None, os.path.abspath(path)
    while not os.path.exists(head):
        first_new, head = head, os.path.dirname(head)
    try:
        os.makedirs(path, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test-", dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(f"--out {path}: cannot create or write the output folder ({exc.strerror or exc})") from None
    finally:
        if first_new is not None and os.path.isdir(first_new):
            import shutil

            shutil.rmtree(first_new, ignore_errors=True)
    return path


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def _finite_or_none(value):
    """``value`` with every infinite or NaN float (nested in dicts, lists and tuples) replaced by None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    return value


def finite_json(value, **kwargs) -> str:
    """``json.dumps`` of ``value`` as strict JSON: an infinite or NaN number is written null.

    Python's ``json`` writes them ``Infinity`` and ``NaN``, which strict parsers (JavaScript's
    ``JSON.parse``, jq) refuse: a result.json with an open bracket ``[50, Infinity]`` could not be read.
    """
    import json

    return json.dumps(_finite_or_none(value), allow_nan=False, **kwargs)


def _vertex_records(points: np.ndarray) -> Iterable[str]:
    # repr() of a Python float is the shortest string that parses back to the
    # same double, so reading the file reproduces the coordinates bit for bit.
    for x, y, z in np.asarray(points, dtype=np.float64).tolist():
        yield f"v {x!r} {y!r} {z!r}\n"


def write_design_obj(path: str | os.PathLike, design: Design) -> None:
    """Write a design as a line-graph OBJ that reads back identically.

    One ``v`` record per vertex and one two-vertex ``l`` record per segment,
    both in the design's order, so vertex indices, segment order and segment
    orientation survive the round trip.

    Parameters
    ----------
    path : str or PathLike
    design : Design
    """
    parts = [f"# xshells design: {design.num_vertices} vertices, {design.num_segments} segments\n"]
    parts.extend(_vertex_records(design.vertices))
    parts.extend(f"l {a + 1} {b + 1}\n" for a, b in np.asarray(design.edges).tolist())
    atomic_write_text(path, "".join(parts))


def write_polylines_obj(path: str | os.PathLike, polylines: Sequence[np.ndarray],
                        closed: Sequence[bool] | None = None) -> None:
    """Write centerlines as OBJ polylines, one ``l`` record each.

    Parameters
    ----------
    path : str or PathLike
    polylines : sequence of array_like, each shape (p_i, 3), p_i >= 2
        Points along each centerline.
    closed : sequence of bool, optional
        Per polyline, whether to join its last point back to its first.
    """
    if closed is None:
        closed = [False] * len(polylines)
    if len(closed) != len(polylines):
        raise ValueError(f"closed has {len(closed)} entries for {len(polylines)} polylines")
    parts = [f"# xshells centerlines: {len(polylines)} polylines\n"]
    records = []
    offset = 1
    for i, (pts, is_closed) in enumerate(zip(polylines, closed)):
        pts = np.asarray(pts, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 2:
            raise ValueError(f"polyline {i} must have shape (p, 3) with p >= 2, got {pts.shape}")
        parts.extend(_vertex_records(pts))
        idx = list(range(offset, offset + len(pts)))
        if is_closed:
            idx.append(offset)
        records.append("l " + " ".join(map(str, idx)) + "\n")
        offset += len(pts)
    parts.extend(records)
    atomic_write_text(path, "".join(parts))
