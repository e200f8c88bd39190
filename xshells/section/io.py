"""Reading cross-sections: ElasticRods JSON files, OBJ contours and gmsh line meshes.

JSON (as in ElasticRods ``examples/cross_sections``)::

    {"type": "Rectangle", "young": 20000, "poisson": 0.3, "params": [12, 8]}

and, for a custom contour, ``{"type": "contour", "path": "profile.obj",
"young": ..., "poisson": ..., "scale": 1}`` with ``path`` relative to the
JSON file (``scale`` > 0, default 1), or ``{"type": "polygon", "points": [[x, y], ...],
"holes": [...], ...}``. Any other key is refused, naming the nearest allowed one.

Contour files (``.obj`` with ``v``/``l`` records, or gmsh ``.msh`` with line
elements) are an edge soup: edges may come in any order and repeat their
end points. End points closer than 1e-8 of the bounding-box diagonal are
merged; every merged vertex must then join exactly two edges. Loops nested
inside the outer loop are holes. Vertices used by no edge are ignored
(ElasticRods uses them as hole markers; nesting tells us the holes).
"""
from __future__ import annotations

import contextlib
import difflib
import json
import math
from io import StringIO
from pathlib import Path

import numpy as np

from ..errors import InputError, check_input_file
from .profiles import Profile, make_profile, points_in_loop, polygon

MERGE_TOL = 1e-8


def _obj_vertex(fields: list, path: Path, lineno: int) -> list:
    """x, y, z of a ``v`` record (z 0 when absent); a record without x and y, or not finite, is refused."""
    shown = " ".join(fields)
    if len(fields) < 3:
        raise InputError(f"{path}:{lineno}: vertex {shown!r} has {len(fields) - 1} coordinate"
                         f"{'s' if len(fields) != 2 else ''}; expected x y [z]")
    try:
        # x y z, then an optional w or r g b that a contour does not use
        coords = [float(v) for v in fields[1:4]]
    except ValueError:
        raise InputError(f"{path}:{lineno}: bad vertex {shown!r} (coordinates must be numbers)") from None
    if not all(math.isfinite(c) for c in coords):
        raise InputError(f"{path}:{lineno}: vertex {shown!r} has a coordinate that is not finite")
    return coords + [0.0] * (3 - len(coords))


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and edges (s, 2) of an OBJ file's ``l`` and ``f`` records."""
    vertices, edges = [], []

    def index(token: str, lineno: int) -> int:
        try:
            i = int(token.split("/")[0])
        except ValueError:
            raise InputError(f"{path}:{lineno}: bad vertex index {token!r}") from None
        return i - 1 if i > 0 else len(vertices) + i

    with open(path, encoding="utf-8", errors="replace") as handle:
        for lineno, line in enumerate(handle, 1):
            fields = line.split()
            if not fields:
                continue
            if fields[0] == "v":
                vertices.append(_obj_vertex(fields, path, lineno))
            elif fields[0] == "l":
                ids = [index(t, lineno) for t in fields[1:]]
                edges.extend(zip(ids[:-1], ids[1:]))
            elif fields[0] == "f":
                ids = [index(t, lineno) for t in fields[1:]]
                edges.extend(zip(ids, ids[1:] + ids[:1]))
    return np.array(vertices, dtype=float).reshape(-1, 3), _boundary_of(np.array(edges, dtype=int).reshape(-1, 2))


def _boundary_of(edges: np.ndarray) -> np.ndarray:
    """Drop edges that appear twice (interior edges of a face mesh); lines appear once."""
    if len(edges) == 0:
        return edges
    key = np.sort(edges, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return edges[counts[inverse.ravel()] == 1]


def _read_msh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) and edges (s, 2) from a gmsh file's line (or triangle) elements."""
    import meshio

    try:
        # meshio prints a stray blank line for some binary msh 2.2 files; keep stdout clean for JSON
        with contextlib.redirect_stdout(StringIO()):
            mesh = meshio.read(path)
    except Exception as exc:  # meshio raises many types for bad files
        raise InputError(f"{path}: cannot read gmsh file ({exc})") from None
    edges = []
    for block in mesh.cells:
        if block.type == "line":
            edges.append(block.data[:, :2])
        elif block.type == "triangle":
            t = block.data
            edges.append(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]))
    edges = np.concatenate(edges) if edges else np.zeros((0, 2), dtype=int)
    points = np.asarray(mesh.points, dtype=float)
    points = np.column_stack([points, np.zeros((len(points), 3 - points.shape[1]))]) if points.shape[1] < 3 \
        else points[:, :3]
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if len(bad):
        raise InputError(f"{path}: node {bad[0] + 1} has a coordinate that is not finite "
                         f"({', '.join(f'{c:g}' for c in points[bad[0]])})")
    return points, _boundary_of(edges)


def _merge_close_points(points: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge points closer than ``tol``; returns unique points (k, 2) and the map (n,) into them."""
    from scipy.cluster.hierarchy import DisjointSet
    from scipy.spatial import cKDTree

    pairs = cKDTree(points).query_pairs(tol, output_type="ndarray")
    groups = DisjointSet(range(len(points)))
    for i, j in pairs:
        groups.merge(int(i), int(j))
    roots = np.array([groups[i] for i in range(len(points))])
    unique_roots, mapping = np.unique(roots, return_inverse=True)
    return points[unique_roots], mapping.ravel()


def loops_from_edges(points: np.ndarray, edges: np.ndarray, name: str) -> list[np.ndarray]:
    """Chain an edge soup into closed loops.

    Parameters
    ----------
    points : ndarray, shape (n, 2)
    edges : ndarray of int, shape (s, 2)
    name : str
        For messages.

    Returns
    -------
    list of ndarray, each shape (n_k, 2)
    """
    if len(edges) == 0:
        raise InputError(f"{name}: no contour edges found")
    used = np.unique(edges)
    if used.min() < 0 or used.max() >= len(points):
        raise InputError(f"{name}: an edge refers to a missing vertex")
    diagonal = float(np.linalg.norm(np.ptp(points[used], axis=0)))
    if diagonal == 0:
        raise InputError(f"{name}: the profile has zero area (all points coincide)")
    merged, mapping = _merge_close_points(points[used], MERGE_TOL * diagonal)
    remap = np.full(len(points), -1)
    remap[used] = mapping
    edges = remap[edges]
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    valence = np.bincount(edges.ravel(), minlength=len(merged))
    for v in np.flatnonzero(valence != 2):
        if valence[v] == 0:
            continue
        x, y = merged[v]
        problem = "is open: a line ends" if valence[v] == 1 else f"branches: {valence[v]} edges meet"
        raise InputError(f"{name}: the contour {problem} at ({x:.6g}, {y:.6g})")
    neighbours = [[] for _ in range(len(merged))]
    for a, b in edges:
        neighbours[a].append(b)
        neighbours[b].append(a)
    visited = np.zeros(len(merged), dtype=bool)
    loops = []
    for start in np.flatnonzero(valence == 2):
        if visited[start]:
            continue
        loop, previous, current = [start], -1, start
        visited[start] = True
        while True:
            a, b = neighbours[current]
            nxt = b if a == previous else a
            if nxt == start:
                break
            visited[nxt] = True
            loop.append(nxt)
            previous, current = current, nxt
        loops.append(merged[loop])
    return loops


def profile_from_loops(loops: list[np.ndarray], name: str) -> Profile:
    """One outer loop and the loops nested directly inside it as holes."""
    depth = [sum(points_in_loop(loop[:1], other)[0] for j, other in enumerate(loops) if j != i)
             for i, loop in enumerate(loops)]
    outer = [loop for loop, d in zip(loops, depth) if d == 0]
    if len(outer) != 1:
        raise InputError(f"{name}: {len(outer)} separate outer contours; a cross-section must be one piece "
                         "(is a hole outside the outer boundary?)")
    if max(depth) > 1:
        raise InputError(f"{name}: a contour lies inside a hole; islands inside holes are not supported")
    holes = [loop for loop, d in zip(loops, depth) if d == 1]
    return polygon(outer[0], holes, name=name)


def load_contour(path, scale: float = 1.0) -> Profile:
    """Profile from an OBJ or gmsh ``.msh`` contour file, coordinates multiplied by ``scale``."""
    path = Path(path)
    check_input_file(path, "contour file")
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".obj":
        points, edges = _read_obj(path)
    elif suffix == ".msh":
        points, edges = _read_msh(path)
    else:
        raise InputError(f"{path}: unknown contour format {suffix!r} (expected .obj or .msh)")
    points = _in_xy_plane(points, edges, path)
    return profile_from_loops(loops_from_edges(points * float(scale), edges, str(path)), str(path))


def _in_xy_plane(points: np.ndarray, edges: np.ndarray, path: Path) -> np.ndarray:
    """The x, y of contour points (n, 3) whose edges lie in one plane z = constant (any constant).

    A contour whose z varies was projected onto xy without a word (a tilted square read as the square);
    one drawn in the xz or yz plane then read as an open or zero-area contour.
    """
    used = np.unique(edges)
    used = used[(used >= 0) & (used < len(points))]  # a missing vertex is loops_from_edges' message
    if len(used) == 0:
        return points[:, :2]
    z = points[used, 2]
    diagonal = float(np.linalg.norm(np.ptp(points[used], axis=0)))
    if np.ptp(z) > MERGE_TOL * diagonal:
        xy = points[used, :2]
        flat = np.ptp(xy, axis=0).min() <= MERGE_TOL * diagonal or \
            np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)[-1] <= MERGE_TOL * diagonal * np.sqrt(len(xy))
        where = "it is drawn in another plane" if flat else "it is not flat in the xy plane"
        raise InputError(f"{path}: the contour's z goes from {z.min():g} to {z.max():g}: {where}; "
                         "draw the section in the xy plane (z constant)")
    return points[:, :2]


def _json_number(data: dict, key: str, path: Path):
    if key not in data:
        return None
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{path}: '{key}' must be a number, got {value!r}")
    return float(value)


def _json_text(value, limit: int = 60) -> str:
    """A value as the file spells it (true, "10", null), cut short for a one-line message."""
    text = json.dumps(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


# The keys each kind of section file may hold. Anything else is refused: a
# misspelt key ("scael") would otherwise be ignored and its default used.
_COMMON_KEYS = ("type", "young", "poisson")
_CONTOUR_FILE_KEYS = _COMMON_KEYS + ("path", "scale")
_POINTS_KEYS = _COMMON_KEYS + ("points", "holes")
_PARAMETRIC_KEYS = _COMMON_KEYS + ("params",)
# Keys that a case file's material uses, which difflib would not match by spelling
_KEY_HINTS = {"E": "young", "nu": "poisson"}


def _check_keys(data: dict, allowed: tuple, kind: str, path: Path) -> None:
    """One line for the first key ``allowed`` lacks, suggesting the nearest allowed one."""
    for key in data:
        if key in allowed:
            continue
        near = [_KEY_HINTS[key]] if _KEY_HINTS.get(key) in allowed else \
            difflib.get_close_matches(key, allowed, n=1)
        hint = f"did you mean {near[0]!r}?" if near else f"allowed keys: {', '.join(allowed)}"
        raise InputError(f"{path}: unknown key {key!r} for a {kind} section ({hint})")


def _json_params(data: dict, path: Path) -> list:
    """``params`` as a list of floats; bool and strings are refused, not converted (true would be 1)."""
    params = data.get("params")
    if not isinstance(params, list):
        shown = "nothing" if "params" not in data else _json_text(params)
        raise InputError(f"{path}: 'params' must be a list of numbers, got {shown}")
    for i, value in enumerate(params):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError(f"{path}: 'params' must be a list of numbers, "
                             f"got {_json_text(value)} at position {i + 1}")
    return [float(value) for value in params]


def _json_pairs(points, what: str, path: Path) -> None:
    """Refuse in one line a JSON point list that is not [[x, y], ...] with finite numbers.

    A third coordinate is refused rather than dropped: a JSON section is drawn in x, y.
    """
    if not isinstance(points, list):
        raise InputError(f"{path}: {what} must be a list of [x, y] pairs, got {_json_text(points)}")
    for i, point in enumerate(points):
        if not (isinstance(point, list) and len(point) == 2
                and all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in point)):
            raise InputError(f"{path}: {what} must be [x, y] pairs of numbers, got {_json_text(point)} "
                             f"at position {i + 1}")
        if not all(math.isfinite(c) for c in point):
            raise InputError(f"{path}: {what} point {i + 1} is not finite ({_json_text(point)})")


def load_section(path, young: float | None = None, poisson: float | None = None) -> tuple[Profile, float, float]:
    """Read a cross-section file.

    Parameters
    ----------
    path : str or Path
        A JSON file ``{type, young, poisson, params}``, or an ``.obj``/``.msh`` contour.
    young, poisson : float, optional
        Override (or, for contours, supply) E and ν.

    Returns
    -------
    (profile, E, nu)
    """
    path = Path(path)
    check_input_file(path, "cross-section file")
    if path.suffix.lower() in (".obj", ".msh"):
        if young is None or poisson is None:
            raise InputError(f"{path}: a contour file has no material; give Young's modulus and Poisson's ratio")
        return load_contour(path), float(young), float(poisson)
    from ..io.strict_json import loads

    try:
        data = loads(path.read_text(encoding="utf-8"), str(path))  # a key given twice is refused too
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or "type" not in data:
        raise InputError(f"{path}: expected an object with 'type', 'young', 'poisson' and 'params'")
    kind = str(data["type"])
    if kind.lower() in ("contour", "custom", "polygon"):
        if "path" in data and "points" in data:
            # one would be ignored; say so rather than pick one
            raise InputError(f"{path}: a {kind} section takes 'path' (a contour file) or 'points', not both")
        allowed = _POINTS_KEYS if "points" in data else _CONTOUR_FILE_KEYS
    else:
        allowed = _PARAMETRIC_KEYS
    _check_keys(data, allowed, kind, path)
    E = young if young is not None else _json_number(data, "young", path)
    nu = poisson if poisson is not None else _json_number(data, "poisson", path)
    if E is None or nu is None:
        missing = "young" if E is None else "poisson"
        raise InputError(f"{path}: missing '{missing}'")
    if allowed is _CONTOUR_FILE_KEYS:
        if "path" not in data:
            raise InputError(f"{path}: a {kind} section needs 'path' (a contour file) or 'points'")
        if not isinstance(data["path"], str):
            raise InputError(f"{path}: 'path' must be a file name (a string), got {_json_text(data['path'])}")
        scale = _json_number(data, "scale", path)
        # 0 is not "unset": a zero or negative scale would collapse or mirror the profile
        if scale is not None and not (math.isfinite(scale) and scale > 0):
            raise InputError(f"{path}: 'scale' must be a positive number, got {_json_text(data['scale'])}")
        contour = path.parent / data["path"]
        if not contour.is_file():
            raise InputError(f"{path}: 'path' names {data['path']!r}, which is not a file (relative to the JSON's folder)")
        return load_contour(contour, scale=1.0 if scale is None else scale), E, nu
    if allowed is _POINTS_KEYS:
        holes = data.get("holes", [])
        _json_pairs(data["points"], "'points'", path)
        if not isinstance(holes, list):
            raise InputError(f"{path}: 'holes' must be a list of point lists, got {_json_text(holes)}")
        for k, hole in enumerate(holes):
            if isinstance(hole, list) and hole and not isinstance(hole[0], list):
                # "holes": [[x, y], ...] is one hole written without its own brackets
                raise InputError(f"{path}: 'holes' must be a list of point lists [[[x, y], ...], ...], "
                                 f"got {_json_text(hole)} as hole {k + 1}")
            _json_pairs(hole, f"hole {k + 1} of 'holes'", path)
        return polygon(data["points"], holes, name=str(path)), E, nu
    return make_profile(kind, _json_params(data, path), name=str(path)), E, nu
