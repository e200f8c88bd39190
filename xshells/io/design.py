"""Reading X-shell designs: line graphs of joints (nodes) and beam segments (edges).

A design is the flat (or deployed) layout of the beam network as drawn in a
CAD tool: a vertex per joint or free end, and a line element per beam segment
between two of them. Two file kinds hold one:

* line-graph OBJ (``v x y z`` and ``l i j [k ...]`` records, as Rhino and
  Blender write them);
* gmsh ``.msh`` with ``line`` elements (the optimized designs of the
  reference code), read with meshio.

The file's vertex order and segment order are kept exactly: per-segment data
such as ``design_parameters.txt`` (rest lengths) list one value per segment in
that order.

Every problem with the input raises :class:`xshells.errors.InputError` with a
single line that names the file, the line (OBJ) or the element/node (gmsh,
0-based as meshio numbers them) and what is wrong.
"""
from __future__ import annotations

import contextlib
import io
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from xshells.errors import InputError, check_input_file

__all__ = [
    "Design",
    "design_from_arrays",
    "read_design",
    "read_obj_design",
    "read_msh_design",
    "read_rest_lengths",
]

# OBJ records that carry nothing for a line graph (grouping, shading, normals,
# texture coordinates, materials, free-form curve headers) and are skipped.
_IGNORED_OBJ_RECORDS = frozenset(
    {"o", "g", "s", "vn", "vt", "vp", "mtllib", "usemtl", "mg", "lod",
     "bevel", "c_interp", "d_interp", "shadow_obj", "trace_obj"}
)

# A segment shorter than this fraction of the bounding-box diagonal counts as
# zero-length: its tangent, and hence its joint frame, is undefined.
_ZERO_LENGTH_RELATIVE = 1e-12


@dataclass(frozen=True, eq=False)
class Design:
    """A beam network: vertices joined by straight segments, in file order.

    Attributes
    ----------
    vertices : ndarray, shape (n, 3), float64
        Vertex positions (joints, free ends, possibly unused vertices).
    edges : ndarray, shape (m, 2), int64
        Segment endpoints as 0-based vertex indices, in the file's order;
        ``edges[s, 0] -> edges[s, 1]`` is segment ``s``'s local direction.
    source : str or None
        The file the design came from, or None when built from arrays.
    vertex_lines, edge_lines : ndarray of int64, shape (n,) / (m,), or None
        The 1-based file line of each vertex / segment (OBJ only), so that
        later checks (valence, connectivity) can point at the file.
    note : str or None
        How the file was read where that matters: a ``.3dm``'s layer, unit
        system and conversion to millimetres.

    Arrays are read-only so a Design can be shared safely.
    """

    vertices: np.ndarray
    edges: np.ndarray
    source: str | None = None
    vertex_lines: np.ndarray | None = field(default=None, repr=False)
    edge_lines: np.ndarray | None = field(default=None, repr=False)
    note: str | None = None  # how the file was read, where it says more than its name (a .3dm's units and layer)

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_segments(self) -> int:
        return int(self.edges.shape[0])

    def where_vertex(self, v: int) -> str:
        """Describe vertex ``v`` for an error message, with its file line if known."""
        text = f"node {v}"
        if self.vertex_lines is not None:
            text += f" (line {int(self.vertex_lines[v])})"
        return text

    def where_edge(self, s: int) -> str:
        """Describe segment ``s`` for an error message, with its file line if known."""
        if self.edge_lines is not None:
            return f"line {int(self.edge_lines[s])}"
        return f"edge {s}"

    def label(self) -> str:
        """The file name to start an error message with."""
        return str(self.source) if self.source is not None else "<arrays>"


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def design_from_arrays(vertices, edges, source: str | os.PathLike | None = None,
                       *, vertex_lines=None, edge_lines=None) -> Design:
    """Build and validate a :class:`Design` from arrays.

    Parameters
    ----------
    vertices : array_like, shape (n, 3) (or (n, 2), padded with z = 0)
    edges : array_like of int, shape (m, 2), 0-based vertex indices
    source : path or None
        Only used to name the design in error messages.
    vertex_lines, edge_lines : array_like of int, shape (n,) / (m,), optional
        1-based file lines, for error messages.

    Raises
    ------
    InputError
        Bad shapes, non-finite coordinates, index out of range, self-loop,
        duplicate edge, zero-length segment, or no segments at all.
    """
    label = str(source) if source is not None else "<arrays>"
    V = np.array(vertices, dtype=np.float64, copy=True)
    if V.ndim == 2 and V.shape[1] == 2:
        V = np.hstack([V, np.zeros((V.shape[0], 1))])
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(f"{label}: vertices must have shape (n, 3), got {V.shape}")
    E_in = np.asarray(edges)
    if E_in.size == 0:
        raise InputError(f"{label}: the design has no line elements (no beam segments)")
    if E_in.ndim != 2 or E_in.shape[1] != 2:
        raise InputError(f"{label}: edges must have shape (m, 2), got {E_in.shape}")
    if not np.issubdtype(E_in.dtype, np.integer):
        if not np.all(np.equal(np.mod(E_in, 1), 0)):
            raise InputError(f"{label}: edge indices must be integers")
    E = E_in.astype(np.int64)
    vl = None if vertex_lines is None else np.asarray(vertex_lines, dtype=np.int64)
    el = None if edge_lines is None else np.asarray(edge_lines, dtype=np.int64)
    design = Design(_readonly(V), _readonly(E), label if source is not None else None,
                    None if vl is None else _readonly(vl),
                    None if el is None else _readonly(el))
    _validate(design)
    return design


#: the farthest a vertex may lie from the origin, in any units (1e12 mm is 1000 km)
MAX_COORDINATE = 1e12


def _validate(d: Design) -> None:
    """Raise InputError for the first defect found, in file order of checks."""
    V, E, label = d.vertices, d.edges, d.label()
    bad_rows = np.flatnonzero(~np.all(np.isfinite(V), axis=1))
    if bad_rows.size:
        v = int(bad_rows[0])
        raise InputError(f"{label}: {d.where_vertex(v)} has a non-finite coordinate {tuple(V[v].tolist())}")
    huge = np.flatnonzero(np.abs(V).max(axis=1) > MAX_COORDINATE)
    if huge.size:  # the solver's squares overflow (1e200: an internal error from SciPy)
        v = int(huge[0])
        raise InputError(f"{label}: {d.where_vertex(v)} lies {float(np.abs(V[v]).max()):.3g} from the origin, beyond "
                         f"{MAX_COORDINATE:g}: check the units (the bundled designs are in mm)")
    out = np.flatnonzero(np.any((E < 0) | (E >= len(V)), axis=1))
    if out.size:
        s = int(out[0])
        raise InputError(f"{label}: {d.where_edge(s)}: vertex index out of range "
                         f"({E[s, 0]}, {E[s, 1]}) with {len(V)} vertices (0-based)")
    loops = np.flatnonzero(E[:, 0] == E[:, 1])
    if loops.size:
        s = int(loops[0])
        raise InputError(f"{label}: {d.where_edge(s)}: self-loop at {d.where_vertex(int(E[s, 0]))}")
    _check_duplicates(d)
    _check_magnitude(d)
    # Work in units of the largest coordinate so huge inputs cannot overflow.
    scale = float(np.max(np.abs(V[np.unique(E)]))) or 1.0
    W = V / scale
    lengths = np.linalg.norm(W[E[:, 1]] - W[E[:, 0]], axis=1)
    diag = float(np.linalg.norm(np.ptp(W[np.unique(E)], axis=0)))
    short = np.flatnonzero(lengths <= _ZERO_LENGTH_RELATIVE * diag)
    if short.size:
        s = int(short[0])
        raise InputError(f"{label}: {d.where_edge(s)}: zero-length segment between "
                         f"{d.where_vertex(int(E[s, 0]))} and {d.where_vertex(int(E[s, 1]))}")
    median = float(np.median(lengths))
    tiny = np.flatnonzero(lengths < _SHORT_RELATIVE * median)
    if tiny.size:
        s = int(tiny[np.argmin(lengths[tiny])])
        raise InputError(f"{label}: {d.where_edge(s)}: segment between {d.where_vertex(int(E[s, 0]))} and "
                         f"{d.where_vertex(int(E[s, 1]))} is {lengths[s] * scale:.3g} long, {lengths[s] / median:.1e} of the "
                         f"median segment ({median * scale:.4g}): too short to simulate beside the others; merge its two "
                         f"joints or redraw it")


# A segment shorter than this fraction of the median segment is refused: its stiffness swamps the
# others' in double precision. Measured on a 4 × 4 grid of 100-long segments with one extra segment:
# 1e-9 and 1e-6 long, the deployment never moved and reported success; 0.01 long, it stalled; 1 long,
# it deployed. The paper's designs and the bundled ones have at least 0.17 of their median.
_SHORT_RELATIVE = 1e-4

# A vertex this many times farther from the others' centre than the design's typical
# size swamps the rest in double precision (their differences round to zero).
_MAGNITUDE_RATIO = 1e9


def _check_magnitude(d: Design) -> None:
    """Name a coordinate so large that the other vertices' differences are lost to round-off."""
    V = d.vertices[np.unique(d.edges)]
    centre = np.median(V, axis=0)
    dist = np.max(np.abs(V - centre), axis=1)
    typical = float(np.median(dist))
    if typical == 0.0:
        typical = float(np.max(dist[dist > 0])) if np.any(dist > 0) else 1.0
    worst = int(np.argmax(dist))
    if dist[worst] > _MAGNITUDE_RATIO * typical:
        v = int(np.unique(d.edges)[worst])
        big = float(np.max(np.abs(d.vertices[v])))
        with np.errstate(over="ignore"):
            ratio = dist[worst] / typical
        times = f"{ratio:.2g} times" if np.isfinite(ratio) else f"more than {_MAGNITUDE_RATIO:g} times"
        raise InputError(f"{d.label()}: {d.where_vertex(v)} has a coordinate of {big:.3g}, {times} "
                         f"the design's typical size ({typical:.3g}): at that magnitude the other vertices' "
                         f"positions are lost to round-off; check the file and its units")


def _check_duplicates(d: Design) -> None:
    E = d.edges
    key = np.sort(E, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if np.all(counts == 1):
        return
    # Report the earliest repeated segment and the segment it repeats.
    seen: dict[tuple[int, int], int] = {}
    for s, (a, b) in enumerate(key.tolist()):
        if (a, b) in seen:
            raise InputError(f"{d.label()}: {d.where_edge(s)}: duplicate edge between "
                             f"{d.where_vertex(a)} and {d.where_vertex(b)}, "
                             f"already given at {d.where_edge(seen[(a, b)])}")
        seen[(a, b)] = s


def read_design(path: str | os.PathLike) -> Design:
    """Read a design, choosing the reader from the file extension.

    Parameters
    ----------
    path : str or PathLike
        ``.obj`` (line-graph OBJ), ``.msh`` (gmsh, line elements) or ``.3dm``
        (Rhino: the lines and polylines of its one curve layer, in mm;
        :func:`xshells.rhino.read_3dm_design` for a layer or sampling).

    Returns
    -------
    Design
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".obj":
        return read_obj_design(path)
    if suffix == ".msh":
        return read_msh_design(path)
    if suffix == ".3dm":
        from ..rhino.read import read_3dm_design

        return read_3dm_design(path)
    raise InputError(f"{path}: unknown design file type {suffix!r} (expected .obj, .msh or .3dm)")


def _read_text(path: str | os.PathLike) -> str:
    check_input_file(path)
    try:
        with open(path, encoding="utf-8") as f:
            return f.read()
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a text file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read file ({exc.strerror or exc})") from None


def _parse_obj_index(token: str, num_vertices_so_far: int, where: str) -> int:
    """Turn one OBJ vertex reference (``7``, ``-1``, ``7/3``) into a 0-based index."""
    head = token.split("/", 1)[0]
    try:
        i = int(head)
    except ValueError:
        raise InputError(f"{where}: malformed vertex index {token!r}") from None
    if i == 0:
        raise InputError(f"{where}: vertex index 0 is invalid (OBJ indices start at 1)")
    # Negative indices count back from the last vertex defined so far.
    return i - 1 if i > 0 else num_vertices_so_far + i


def read_obj_design(path: str | os.PathLike) -> Design:
    """Read a line-graph OBJ: ``v`` records and ``l`` (poly)line records.

    ``l a b c`` is a polyline and yields segments a-b and b-c. Indices are
    1-based; negative ones are relative to the vertices defined so far.
    Comments, blank lines and grouping/shading/normal/texture records are
    skipped; faces and unknown records are errors, since silently dropping
    them would change the design.
    """
    text = _read_text(path)
    label = str(path)
    coords: list[tuple[float, float, float]] = []
    vertex_lines: list[int] = []
    edges: list[tuple[int, int]] = []
    edge_lines: list[int] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        content = raw.split("#", 1)[0].strip()
        if not content:
            continue
        tokens = content.split()
        keyword, args = tokens[0], tokens[1:]
        where = f"{label}: line {lineno}"
        if keyword == "v":
            coords.append(_parse_obj_vertex(args, where))
            vertex_lines.append(lineno)
        elif keyword == "l":
            if len(args) < 2:
                raise InputError(f"{where}: line record needs at least 2 vertex indices, got {len(args)}")
            idx = [_parse_obj_index(t, len(coords), where) for t in args]
            for a, b in zip(idx[:-1], idx[1:]):
                edges.append((a, b))
                edge_lines.append(lineno)
        elif keyword in _IGNORED_OBJ_RECORDS:
            continue
        elif keyword == "f":
            raise InputError(f"{where}: face record 'f' in a line-graph design (only 'l' line elements are allowed)")
        else:
            raise InputError(f"{where}: unknown OBJ record {keyword!r}")
    if not edges:
        raise InputError(f"{label}: the design has no line elements ('l' records)")
    return design_from_arrays(
        np.array(coords, dtype=np.float64).reshape(-1, 3),
        np.array(edges, dtype=np.int64),
        source=label, vertex_lines=vertex_lines, edge_lines=edge_lines,
    )


def _parse_obj_vertex(args: list[str], where: str) -> tuple[float, float, float]:
    # 3 coordinates, optionally a weight (4) or an RGB colour (6) after them.
    if len(args) not in (3, 4, 6):
        raise InputError(f"{where}: vertex record needs 3 coordinates, got {len(args)} values")
    try:
        values = [float(t) for t in args]
    except ValueError:
        raise InputError(f"{where}: malformed vertex record 'v {' '.join(args)}'") from None
    x, y, z = values[:3]
    if not all(np.isfinite(values[:3])):
        raise InputError(f"{where}: non-finite vertex coordinate ({x}, {y}, {z})")
    return x, y, z


def read_msh_design(path: str | os.PathLike) -> Design:
    """Read the line elements of a gmsh ``.msh`` file (all ``line`` cell blocks, in order).

    Node indices in error messages are 0-based, as meshio numbers them.
    """
    import meshio  # deferred: meshio is slow to import and only needed here

    label = str(path)
    check_input_file(path)
    if not os.path.isfile(path):
        raise InputError(f"{label}: cannot read file (no such file)")
    chatter = io.StringIO()
    try:
        # meshio prints its parse errors and may call sys.exit on a bad file.
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            try:
                mesh = meshio.read(path, file_format="gmsh")
            except ValueError:
                # meshio cannot read back the $NodeData of an ASCII file it wrote itself ("could not be read
                # to its end"): a design needs its nodes and elements only, so read it without its data blocks
                mesh = _read_ascii_msh_without_data(path, meshio)
                if mesh is None:
                    raise
    except (Exception, SystemExit) as exc:
        # On SystemExit meshio's printed text only repeats the file name; an IndexError is an element
        # naming a node the file does not have ("index 6 is out of bounds for axis 0 with size 4")
        reason = ("not a valid gmsh file" if isinstance(exc, SystemExit) else
                  f"an element refers to a node the file does not define: {exc}" if isinstance(exc, IndexError) else
                  f"{chatter.getvalue()} {exc}")
        msg = " ".join(reason.split())
        raise InputError(f"{label}: cannot read gmsh file ({msg})") from None
    blocks = [c.data for c in mesh.cells if c.type == "line"]
    if not blocks or sum(len(b) for b in blocks) == 0:
        kinds = sorted({c.type for c in mesh.cells}) or ["none"]
        raise InputError(f"{label}: the design has no line elements (cell types: {', '.join(kinds)})")
    # anything else beside the lines (a triangle, a quad) would be dropped without a word: say so instead
    # (point elements carry nothing for a line graph and are skipped, as gmsh writes them for its points)
    other = {}
    for c in mesh.cells:
        if c.type not in ("line", "vertex") and len(c.data):
            other[c.type] = other.get(c.type, 0) + len(c.data)
    if other:
        listed = ", ".join(f"{n} {kind} element{'s' * (n != 1)}" for kind, n in sorted(other.items()))
        raise InputError(f"{label}: the design holds {listed} besides its line elements: a design is a line graph "
                         "of beam segments only (a target surface goes to --target-surface)")
    return design_from_arrays(mesh.points, np.concatenate(blocks, axis=0), source=label)


_DATA_BLOCKS = ("$NodeData", "$ElementData", "$ElementNodeData")


def _read_ascii_msh_without_data(path, meshio):
    """An ASCII gmsh file read by meshio without its data blocks (None for a binary file: they read as they are)."""
    import tempfile

    with open(path, "rb") as fh:
        head = fh.read(64).split()
    if len(head) < 3 or head[0] != b"$MeshFormat" or head[2] != b"0":  # "$MeshFormat 2.2 0 8": 0 is ASCII
        return None
    with open(path, encoding="utf-8", errors="replace") as fh:
        kept, skip = [], None
        for line in fh:
            word = line.strip()
            if skip is None and word in _DATA_BLOCKS:
                skip = "$End" + word[1:]
            elif skip is not None:
                if word == skip:
                    skip = None
            else:
                kept.append(line)
    with tempfile.NamedTemporaryFile("w", suffix=".msh", delete=False, encoding="utf-8") as tmp:
        tmp.writelines(kept)
    try:
        return meshio.read(tmp.name, file_format="gmsh")
    finally:
        os.unlink(tmp.name)


#: A median ratio of rest length to drawn segment length beyond this factor (either way) is a units mistake
#: (a file in cm or m for a design in mm), not a design: the reference's designs draw their flat layouts at
#: their rest lengths (ratio 1 to within 1e-3), and an inverse design's within a few per cent.
REST_LENGTH_RATIO = 3.0


def read_rest_lengths(path: str | os.PathLike, num_segments: int, design: Design | None = None) -> np.ndarray:
    """Read per-segment rest lengths (``design_parameters.txt``).

    Format, as in every such file of the reference data: one decimal number
    per line (often space-padded on the left, the last line possibly without
    a newline), one per segment in the design file's segment order. Any
    whitespace separation is accepted; ``#`` starts a comment.

    Parameters
    ----------
    path : str or PathLike
    num_segments : int
        The design's segment count; the file must hold exactly this many values.
    design : Design, optional
        The design they belong to: rest lengths a median more than :data:`REST_LENGTH_RATIO` times
        longer or shorter than its drawn segments are refused (other units).

    Returns
    -------
    ndarray, shape (num_segments,), float64
        Rest length of each segment (to be split evenly over its k edges).
    """
    text = _read_text(path)
    values: list[float] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        for token in raw.split("#", 1)[0].split():
            try:
                value = float(token)
            except ValueError:
                raise InputError(f"{path}: line {lineno}: malformed rest length {token!r}") from None
            if not np.isfinite(value):
                raise InputError(f"{path}: line {lineno}: non-finite rest length {token!r}")
            if value <= 0:
                raise InputError(f"{path}: line {lineno}: non-positive rest length {value!r}")
            values.append(value)
    if len(values) != num_segments:
        raise InputError(f"{path}: {len(values)} rest lengths for a design with {num_segments} segments")
    p = np.array(values, dtype=np.float64)
    if design is not None:  # the solve failed on such files with "reduced variable 57 is not finite"
        drawn = np.linalg.norm(design.vertices[design.edges[:, 1]] - design.vertices[design.edges[:, 0]], axis=1)
        ratio = float(np.median(p / np.maximum(drawn, np.finfo(float).tiny)))
        if not 1.0 / REST_LENGTH_RATIO <= ratio <= REST_LENGTH_RATIO:
            raise InputError(f"{path}: the rest lengths are a median {ratio:.3g}x the design's drawn segment lengths: "
                             "are they in the design's units?")
    return p
