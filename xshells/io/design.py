"""Reading X-shell designs: line graphs of joints (nodes) and beam segments (edges).

A design is the flat (or deployed) layout of the beam network as drawn in a
CAD tool: a vertex per joint or free end, and a line element per beam segment
between two of them. Two file kinds hold one:

* line-graph OBJ (``v x y z`` and ``l i j [k ...]`` records, as Rhino and
  Blender write them);
* gmsh ``.msh`` with ``line`` elements (the optimized designs of the
  reference code), versions 2.2 and 4.1, ASCII or binary.

The file's vertex order and segment order are kept exactly: per-segment data
such as ``design_parameters.txt`` (rest lengths) list one value per segment in
that order.

Every problem with the input raises :class:`xshells.errors.InputError` with a
single line that names the file, the line (OBJ, ASCII gmsh) or the section,
node or element (gmsh: as the file numbers them while it is read; 0-based
afterwards, in the design's own checks) and what is wrong.
"""
from __future__ import annotations

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


#: the design files :func:`read_design` reads, by extension (lower case)
DESIGN_SUFFIXES = (".obj", ".msh", ".3dm")


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
    if Path(path).is_dir():  # its suffix is '' (a case's "file": "."), which read as "unknown design file type ''"
        raise InputError(f"{path}: a folder, not a design file ({', '.join(DESIGN_SUFFIXES[:-1])} or "
                         f"{DESIGN_SUFFIXES[-1]})")
    suffix = Path(path).suffix.lower()
    if suffix == ".obj":
        return read_obj_design(path)
    if suffix == ".msh":
        return read_msh_design(path)
    if suffix == ".3dm":
        from ..rhino.read import read_3dm_design

        return read_3dm_design(path)
    raise InputError(f"{path}: unknown design file type {suffix!r} (expected {', '.join(DESIGN_SUFFIXES[:-1])} "
                     f"or {DESIGN_SUFFIXES[-1]})")


def _read_text(path: str | os.PathLike) -> str:
    check_input_file(path)
    try:
        with open(path, encoding="utf-8-sig") as f:  # -sig: a byte-order mark (Windows editors write one) is dropped
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
    written: list[tuple[int, list[str], list[int]]] = []  # each 'l' record's line, its indices as written, 0-based
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
            for i, t in zip(idx, args):
                if i < 0:  # a negative index reaching back past the first vertex: say it as written
                    raise InputError(f"{where}: vertex index {t.split('/', 1)[0]} is out of range: it counts back "
                                     f"from the last vertex defined so far, and only {len(coords)} are")
            written.append((lineno, args, idx))
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
    # A positive index may name a vertex defined further down, so the range is checked once all are read,
    # and named as the file writes it (the array check said "(0, 98) ... (0-based)" for "l 1 99").
    for lineno, args, idx in written:
        for i, t in zip(idx, args):
            if i >= len(coords):
                raise InputError(f"{label}: line {lineno}: vertex index {t.split('/', 1)[0]} is out of range: the "
                                 f"file defines {len(coords)} vertices")
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
    """Read the line elements of a gmsh ``.msh`` file (versions 2.2 and 4.1, ASCII or binary), in file order.

    Every value is checked as it is read: an error names the line (ASCII) or the section, and the
    node and element numbers as the file writes them. Node indices in the design's own checks (a
    duplicate edge) are 0-based, in the order of the file's nodes.
    """
    label = str(path)
    check_input_file(path)
    try:
        with open(path, "rb") as fh:
            msh = _Msh(fh.read(), label)
    except OSError as exc:
        raise InputError(f"{label}: cannot read file ({exc.strerror or exc})") from None
    points, lines, other = msh.read()
    if not lines:
        kinds = sorted(other) or ["none"]
        raise InputError(f"{label}: the design has no line elements (cell types: {', '.join(kinds)})")
    # anything else beside the lines (a triangle, a quad) would be dropped without a word: say so instead
    # (point elements carry nothing for a line graph and are skipped, as gmsh writes them for its points)
    other.pop("vertex", None)
    if other:
        listed = ", ".join(f"{n} {kind} element{'s' * (n != 1)}" for kind, n in sorted(other.items()))
        raise InputError(f"{label}: the design holds {listed} besides its line elements: a design is a line graph "
                         "of beam segments only (a target surface goes to --target-surface)")
    return design_from_arrays(points, np.asarray(lines, dtype=np.int64).reshape(-1, 2), source=label)


class _Msh:
    """Reads the nodes and elements of a gmsh file, line by line (binary sections byte by byte).

    meshio, which read designs before, took whatever numbers came next: a line element of three
    nodes shifted every later one, a node numbered 0 became the last node, and a damaged file failed
    with its internals ("cannot reshape array of size 7 into shape (4,3)").
    """

    def __init__(self, data: bytes, label: str):
        self.data, self.label = data, label
        self.pos = self.lineno = 0  # where the next line begins; the number of the last line read
        self.version, self.binary, self.order = "2", False, "<"

    def error(self, what: str, lineno: int | None = None) -> InputError:
        return InputError(f"{self.label}: line {lineno or self.lineno}: {what}")

    def read(self) -> tuple[np.ndarray, list, dict]:
        """Nodes (n, 3), line elements as pairs of 0-based node indices, and the count of every other kind."""
        self._read_format()
        points = lines = None
        other: dict = {}
        while (line := self.line()) is not None:
            if not line.startswith("$"):
                raise self.error(f"expected a section such as $Nodes or $Elements, got {_shown(line)}")
            if line == "$Nodes" and points is None:
                points, index = self._read_nodes()
            elif line == "$Elements" and lines is None:
                if points is None:
                    raise self.error("$Elements comes before $Nodes")
                lines = self._read_elements(index, other)
            elif line in ("$Nodes", "$Elements"):
                raise self.error(f"a second {line} section")
            else:  # $Entities, $PhysicalNames, $NodeData, ...: nothing a design needs
                self._skip_to("$End" + line[1:], line)
        for section, found in (("$Nodes", points), ("$Elements", lines)):
            if found is None:
                raise InputError(f"{self.label}: the file has no {section} section")
        return points, lines, other

    # ---- lines and bytes

    def line(self) -> str | None:
        """The next line that is not blank, stripped; None at the end of the file."""
        while self.pos < len(self.data):
            end = self.data.find(b"\n", self.pos)
            end = len(self.data) if end < 0 else end
            text = self.data[self.pos:end].strip()
            self.pos, self.lineno = end + 1, self.lineno + 1
            if text:
                return text.decode("latin-1")  # any byte: a binary file's garbage still reads as text here
        return None

    def _fields(self, section: str, what: str, kind=int, size: int | None = None) -> list:
        """The next line of ``section`` as numbers (``size`` of them, if given)."""
        line = self.line()
        if line is None:
            raise InputError(f"{self.label}: the file ends inside {section}, before {what} (a truncated file?)")
        if line.startswith("$"):
            raise self.error(f"{section} ends before {what}")
        try:
            values = [kind(v) for v in line.split()]
            if size is not None and len(values) != size:
                raise ValueError
        except ValueError:
            count = "" if size is None else f"{size} "
            numbers = f"{count}{'whole ' * (kind is int)}number{'s' * (size != 1)}"
            raise self.error(f"{what}: expected {numbers}, got {_shown(line)}") from None
        return values

    def _take(self, items: int, dtype, section: str, what: str) -> np.ndarray:
        """``items`` values of ``dtype`` from a binary section ("i4", "u8", "f8" in the file's byte order, or a
        structured dtype)."""
        dtype = np.dtype(self.order + dtype if isinstance(dtype, str) else dtype)
        size = items * dtype.itemsize
        if items < 0 or self.pos + size > len(self.data):
            raise InputError(f"{self.label}: the file ends inside {section}, in {what} (a truncated file?)")
        chunk = self.data[self.pos:self.pos + size]
        self.pos += size
        self.lineno += chunk.count(b"\n")
        return np.frombuffer(chunk, dtype)

    def _numbers(self, section: str, what: str, ints: int, sizes: int = 0) -> list:
        """A header: ``ints`` int32 then ``sizes`` size_t in binary, one line of whole numbers in ASCII."""
        if not self.binary:
            return self._fields(section, what, int, ints + sizes)
        return (self._take(ints, "i4", section, what).tolist() + self._take(sizes, "u8", section, what).tolist())

    def _expect(self, marker: str, after: str) -> None:
        line = self.line()
        if line is None:
            raise InputError(f"{self.label}: the file ends before {marker}, after {after} (a truncated file?)")
        if line != marker:
            raise self.error(f"expected {marker} after {after}, got {_shown(line)}")

    def _skip_to(self, marker: str, section: str) -> None:
        """Past the line that ends with ``marker``: a binary data block runs straight into its end marker
        (the reference's files write no line break before ``$EndNodeData``)."""
        found = self.data.find(marker.encode(), self.pos)
        while found >= 0 and self.data[found + len(marker):found + len(marker) + 1].strip():  # $EndNodeDataX
            found = self.data.find(marker.encode(), found + 1)
        if found < 0:
            raise self.error(f"{section} is not closed by {marker} (a truncated file?)")
        self.lineno += self.data.count(b"\n", self.pos, found)
        self.pos = found
        self.line()

    # ---- sections

    def _read_format(self) -> None:
        line = self.line()
        while line == "$Comments":
            self._skip_to("$EndComments", "$Comments")
            line = self.line()
        if line is None:
            raise InputError(f"{self.label}: the file is empty, not a gmsh file")
        if line != "$MeshFormat":
            begins = (f"it begins with {_shown(line)}, not $MeshFormat" if line.isascii() and line.isprintable()
                      else "it does not begin with $MeshFormat")  # binary data: its bytes say nothing
            raise self.error(f"not a gmsh file: {begins}")
        fields = (self.line() or "").split()
        if len(fields) != 3 or fields[1] not in ("0", "1") or fields[2] != "8":
            raise self.error(f"$MeshFormat must read 'version file-type 8' (file-type 0 for ASCII, 1 for binary), "
                             f"got {_shown(' '.join(fields))}")
        if fields[0] not in ("2", "2.0", "2.1", "2.2", "4.1"):
            raise self.error(f"gmsh format version {_shown(fields[0])} is not supported (2.2 and 4.1 are)")
        self.version, self.binary = fields[0][0], fields[1] == "1"
        if self.binary:  # the integer 1, in the file's byte order
            one = self.data[self.pos:self.pos + 4]
            if one not in (_ONE["<"], _ONE[">"]):
                raise self.error("$MeshFormat of a binary file must hold the integer 1 after its version line")
            self.order = "<" if one == _ONE["<"] else ">"
            self._take(1, "i4", "$MeshFormat", "its integer 1")
        self._expect("$EndMeshFormat", "the format")

    def _read_nodes(self) -> tuple[np.ndarray, dict]:
        """``$Nodes``: coordinates (n, 3) and node number -> 0-based index."""
        if self.version == "2":  # a count (a line, in binary files too), then per node: number x y z
            n, blocks = self._fields("$Nodes", "the number of nodes", int, 1)[0], [None]
        else:  # block count, node count, lowest and highest number; per block: dim, entity, parametric, count
            head = self._numbers("$Nodes", "its header (block count, node count, lowest and highest number)", 0, 4)
            n, blocks = head[1], []
        if n < 0:
            raise self.error(f"the number of nodes must be 0 or more, got {n}")
        if 8 * n > len(self.data):  # a node takes 8 bytes at the least ("1 0 0 0" and its line break)
            raise self.error(f"$Nodes announces {n} nodes, more than the file can hold")
        points, tags, lines = np.empty((n, 3)), [], []  # lines: of each node's number, in an ASCII file
        for b in range(len(blocks) if self.version == "2" else head[0]):
            if self.version == "2":
                count, width = n, 3
            else:
                dim, _, parametric, count = self._numbers("$Nodes", f"the header of node block {b + 1}", 3, 1)
                width = 3 + (dim if parametric else 0)  # parametric nodes add their u (v, w)
            if not 0 <= count <= n - len(tags):
                raise self.error(f"$Nodes announces {n} nodes, its blocks hold more")
            first = len(tags)
            if self.binary:
                if self.version == "2":  # per node: its number (int32), then x, y, z
                    rec = self._take(count, [("tag", self.order + "i4"), ("x", self.order + "f8", (3,))], "$Nodes",
                                     f"its {n} nodes")
                    block_tags, xyz = rec["tag"], rec["x"]
                else:  # the numbers (size_t), then the coordinates
                    block_tags = self._take(count, "u8", "$Nodes", f"node block {b + 1}")
                    xyz = self._take(count * width, "f8", "$Nodes", f"node block {b + 1}").reshape(count, width)[:, :3]
                tags += block_tags.tolist()
                points[first:first + count] = xyz
            elif self.version == "2":
                for i in range(count):
                    values = self._fields("$Nodes", f"node {i + 1} of {n} ('number x y z')", float, 4)
                    if not values[0].is_integer():
                        raise self.error(f"a node number must be a whole number, got {values[0]:g}")
                    tags.append(int(values[0]))
                    points[first + i] = values[1:]
                    lines.append(self.lineno)
            else:
                for i in range(count):
                    tags += self._fields("$Nodes", f"the number of node {first + i + 1} of {n}", int, 1)
                    lines.append(self.lineno)
                for i in range(count):
                    values = self._fields("$Nodes", f"the coordinates of node {tags[first + i]}", float, width)
                    points[first + i] = values[:3]
        if len(tags) != n:
            raise self.error(f"$Nodes announces {n} nodes, its blocks hold {len(tags)}")
        where = (lambda i: f"line {lines[i]}") if lines else (lambda i: f"$Nodes, node {i + 1} of {n}")
        numbers = np.array(tags, dtype=np.int64)
        for i in np.flatnonzero(numbers < 1)[:1]:
            raise InputError(f"{self.label}: {where(i)}: a node number must be 1 or more, got {tags[i]}")
        index = dict(zip(tags, range(n)))
        if len(index) < n:  # a number given twice: the dict kept its last place
            first = next(i for i, tag in enumerate(tags) if index[tag] != i)
            raise InputError(f"{self.label}: {where(index[tags[first]])}: node {tags[first]} is defined twice (first "
                             f"at {where(first)})")
        for i in np.flatnonzero(~np.isfinite(points).all(axis=1))[:1]:
            raise InputError(f"{self.label}: {where(i)}: node {tags[i]} has a non-finite coordinate "
                             f"{tuple(points[i].tolist())}")
        self._expect("$EndNodes", f"the {n} nodes")
        return points, index

    def _read_elements(self, index: dict, other: dict) -> list:
        """``$Elements``: the line elements as 0-based node pairs; ``other`` counts the rest by kind."""
        kinds = _element_kinds()
        lines, done = [], 0

        def add(number: int, kind: str, nodes: list, where: str) -> None:
            missing = [v for v in nodes if v not in index]
            if missing:
                raise InputError(f"{self.label}: {where}: element {number} refers to node {missing[0]}, which $Nodes "
                                 "does not define")
            if kind == "line":
                lines.append([index[nodes[0]], index[nodes[1]]])
            else:
                other[kind] = other.get(kind, 0) + 1

        numbers = np.array(sorted(index), dtype=np.int64)
        positions = np.array([index[v] for v in numbers.tolist()], dtype=np.int64)

        def add_block(rows: np.ndarray, kind: str, first: int) -> None:
            """A binary block: element numbers in column 0, the nodes from column ``first`` on."""
            nodes = rows[:, first:].astype(np.int64)
            at = np.minimum(np.searchsorted(numbers, nodes), max(len(numbers) - 1, 0))
            known = numbers[at] == nodes if len(numbers) else np.zeros(nodes.shape, bool)
            if not known.all():
                e, k = np.argwhere(~known)[0]
                add(int(rows[e, 0]), kind, [int(nodes[e, k])], "$Elements")
            if kind == "line":
                lines.extend(positions[at].tolist())
            else:
                other[kind] = other.get(kind, 0) + len(rows)

        def kind_of(etype: int, where: str) -> tuple:
            if etype not in kinds:
                raise InputError(f"{self.label}: {where}: element type {etype} is not a gmsh element type")
            return kinds[etype]

        if self.version == "2":  # a line, in binary files too
            n = self._fields("$Elements", "the number of elements", int, 1)[0]
        else:
            n = self._numbers("$Elements", "its header (block count, element count, lowest and highest number)", 0, 4)[1]
        if self.version == "2" and not self.binary:  # per element: number, type, tag count, tags, nodes
            for i in range(n):
                values = self._fields("$Elements", f"element {i + 1} of {n} ('number type tag-count tags... nodes')")
                if len(values) < 3:
                    raise self.error(f"an element is 'number type tag-count tags... nodes...', got {len(values)} "
                                     f"number{'s' * (len(values) != 1)}")
                number, etype, ntags = values[:3]
                kind, nodes = kind_of(etype, f"line {self.lineno}")
                if ntags < 0 or len(values) != 3 + ntags + nodes:
                    raise self.error(f"element {number}: a {kind} element with {ntags} tags is {3 + ntags + nodes} "
                                     f"numbers, this line has {len(values)}")
                add(number, kind, values[3 + ntags:], f"line {self.lineno}")
            done = n
        while done < n:  # blocks: version 2 binary, and version 4
            where = f"$Elements, the block after {done} of its {n} elements"
            if self.version == "2":  # type, count, tag count; per element: number, tags, nodes (all int32)
                etype, count, ntags = self._numbers("$Elements", f"the block after {done} of its {n} elements", 3)
            else:  # dim, entity, type, count; per element: number and nodes
                _, _, etype, count = self._numbers("$Elements", f"the header of the block after {done} of its {n} "
                                                   "elements", 3, 1)
                ntags = 0
            kind, nodes = kind_of(etype, f"line {self.lineno}" if not self.binary else where)
            if not 0 < count <= n - done or ntags < 0:
                raise InputError(f"{self.label}: {where}: a block of {count} elements does not fit in the {n} "
                                 "announced")
            width = 1 + ntags + nodes
            if self.binary:
                rows = self._take(count * width, "i4" if self.version == "2" else "u8", "$Elements",
                                  f"the block after {done} of its {n} elements")
                add_block(rows.reshape(count, width), kind, 1 + ntags)
            else:
                for _ in range(count):
                    values = self._fields("$Elements", f"a {kind} element ('number' and {nodes} nodes)", int, width)
                    add(values[0], kind, values[1:], f"line {self.lineno}")
            done += count
        self._expect("$EndElements", f"the {n} elements")
        return lines


_ONE = {"<": (1).to_bytes(4, "little"), ">": (1).to_bytes(4, "big")}


def _shown(text: str, limit: int = 40) -> str:
    """``text`` for a message: quoted, cut short."""
    return repr(text if len(text) <= limit else text[:limit] + "...")


# gmsh's element types 1-31 (the gmsh reference manual, "MSH file format": type number, node count), named as
# meshio names them: the lines, surfaces and points a design holds, and the volumes a file may hold beside them
_GMSH_ELEMENTS = {
    1: ("line", 2), 2: ("triangle", 3), 3: ("quad", 4), 4: ("tetra", 4), 5: ("hexahedron", 8), 6: ("wedge", 6),
    7: ("pyramid", 5), 8: ("line3", 3), 9: ("triangle6", 6), 10: ("quad9", 9), 11: ("tetra10", 10),
    12: ("hexahedron27", 27), 13: ("wedge18", 18), 14: ("pyramid14", 14), 15: ("vertex", 1), 16: ("quad8", 8),
    17: ("hexahedron20", 20), 18: ("wedge15", 15), 19: ("pyramid13", 13), 20: ("triangle9", 9),
    21: ("triangle10", 10), 22: ("triangle12", 12), 23: ("triangle15", 15), 24: ("triangle15", 15),
    25: ("triangle21", 21), 26: ("line4", 4), 27: ("line5", 5), 28: ("line6", 6), 29: ("tetra20", 20),
    30: ("tetra35", 35), 31: ("tetra56", 56),
}


def _element_kinds() -> dict:
    """gmsh element type -> (its name, its number of nodes): the table above, and the higher orders meshio knows.

    meshio's table is private (``meshio.gmsh.common``): where a release moves it, the types above still read.
    """
    kinds = dict(_GMSH_ELEMENTS)
    try:
        from meshio._common import num_nodes_per_cell
        from meshio.gmsh.common import _gmsh_to_meshio_type

        for t, name in _gmsh_to_meshio_type.items():
            kinds.setdefault(t, (name, num_nodes_per_cell[name]))
    except (ImportError, AttributeError, KeyError):
        pass
    return kinds


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
