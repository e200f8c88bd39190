"""Reading a design from a Rhino ``.3dm`` file.

A design is the lines and polylines of one layer: each polyline vertex is a
joint or a free end, and consecutive vertices are joined by a segment.
Points closer than the file's absolute tolerance are the same vertex, so
curves drawn end to end join. An end that misses another vertex by more than
the tolerance but less than ``NEAR_MISS`` of the design's median segment is
refused, with where it is: that is a join drawn a little off, not a free end.
A curved curve is refused unless ``sample`` asks for it to be replaced by that
many straight segments. Coordinates are converted from the file's unit system
to millimetres (the note says so).

Blocks are read as Rhino shows them: each placement (an instance reference)
adds its definition's objects, moved by the placement's transform, on their
own layers; a definition's objects are never read where they are stored.
"""
from __future__ import annotations

import dataclasses
import os

import numpy as np

from ..errors import InputError, check_input_file
from ..io.design import Design, design_from_arrays

RHINO_UNITS_TO_MM = {"Millimeters": 1.0, "Centimeters": 10.0, "Decimeters": 100.0, "Meters": 1000.0,
                     "Kilometers": 1e6, "Microns": 1e-3, "Inches": 25.4, "Feet": 304.8, "Yards": 914.4}
# An end this close to another vertex, relative to the design's median segment, but farther than the
# tolerance, is a missed join. A share of the segments, not a multiple of the tolerance: 100 tolerances
# refused a valid design saved in metres with a 1 mm tolerance (its free ends 30 mm from a joint) and let a
# 2 mm miss through at a 0.01 mm tolerance. The bundled designs' free ends are at least 0.197 of the median
# segment from any other vertex (nonuniform_linkage.obj).
NEAR_MISS = 0.05
#: the most straight segments one curve is sampled into (--sample)
MAX_SAMPLE = 1000
# what ``read_design`` uses for a .3dm when not told: set by the command line's --layer and --sample
# (and the target surface's layer: --target-layer, a layer of its own as the surface is often another file's)
_DEFAULTS = {"layer": None, "sample": None, "target_layer": None}


def set_defaults(layer: str | None = None, sample: int | None = None, target_layer: str | None = None) -> None:
    """The layers and sampling that :func:`xshells.io.read_design` and :func:`read_3dm_surface` use for ``.3dm``
    files when not told (the CLI's --layer, --sample and --target-layer)."""
    if sample is not None and not 1 <= sample <= MAX_SAMPLE:
        # each sample is a beam segment: 1e9 of them filled 24 GB before anything was said
        raise InputError(f"--sample must be from 1 to {MAX_SAMPLE} segments per curve, got {sample}")
    _DEFAULTS.update(layer=layer, sample=sample, target_layer=target_layer)


def get_defaults() -> dict:
    """The options :func:`set_defaults` was given, for :func:`set_defaults` in a worker process."""
    return dict(_DEFAULTS)


def _open(path):
    try:
        import rhino3dm
    except ImportError:  # pragma: no cover (a dependency)
        raise InputError(f"{path}: reading .3dm needs the rhino3dm package (pip install rhino3dm)") from None
    check_input_file(path)
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such file")
    f = rhino3dm.File3dm.Read(str(path))
    if f is None:
        raise InputError(f"{path}: not a readable Rhino .3dm file")
    return rhino3dm, f


def _units(path, f) -> tuple[str, float]:
    name = f.Settings.ModelUnitSystem.name
    if name not in RHINO_UNITS_TO_MM:
        raise InputError(f"{path}: model unit system {name!r} is not supported "
                         f"(use one of {', '.join(RHINO_UNITS_TO_MM)}; in Rhino: Units)")
    return name, RHINO_UNITS_TO_MM[name]


def file_units(path) -> str:
    """The unit system a ``.3dm`` file states (e.g. ``"Meters"``); refused in one line if unsupported."""
    _, f = _open(os.fspath(path))
    return _units(path, f)[0]


def _layer_names(f) -> list[str]:
    return [layer.FullPath or layer.Name for layer in f.Layers]


def _pick_layer(path, names: list[str], layer: str) -> int:
    """The index of the layer ``layer`` names: its full path, or else the last part of exactly one layer's path."""
    exact = [k for k, n in enumerate(names) if n == layer]
    if exact:
        return exact[0]
    matches = [k for k, n in enumerate(names) if n.split("::")[-1] == layer]
    if not matches:
        raise InputError(f"{path}: no layer {layer!r} (layers: {', '.join(repr(n) for n in names) or 'none'})")
    if len(matches) > 1:  # the first one was taken: the user may have meant the other
        raise InputError(f"{path}: layer {layer!r} is ambiguous ({', '.join(repr(names[k]) for k in matches)}): "
                         "give its full path")
    return matches[0]


def _xform(path, ref, label: str) -> tuple[np.ndarray, str | None]:
    """A block placement's transform as a 4 x 4 array, and why it cannot be read (else None).

    Only a similarity (a rigid motion, mirror or uniform scale) is taken, as it keeps the beams' shape: a
    stretched or sheared block would change it behind the drawing's back. The reason is given, not raised: a
    stretched block of other things (a title block) does not stop the design from being read.
    """
    X = ref.Xform
    M = np.array([[getattr(X, f"M{r}{c}") for c in range(4)] for r in range(4)], float)
    A = M[:3, :3]
    if not np.all(np.isfinite(M)):
        return M, f"{path}: {label} has a non-finite transform"
    scale2 = float(np.trace(A.T @ A)) / 3.0
    if (np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-12 or not scale2 > 0
            or np.abs(A.T @ A - scale2 * np.eye(3)).max() > 1e-9 * scale2):
        return M, (f"{path}: {label} is stretched, sheared or projected: only a move, rotation, mirror or uniform "
                   "scale of a block is read (in Rhino: Explode it to use the changed geometry)")
    return M, None


def _placed(rhino3dm, path, f) -> list[tuple]:
    """The objects the model shows: ``(label, geometry, layer index, transform or None, refused)``.

    Top-level objects as they are; each block placement adds its definition's objects through its transform
    (nested blocks too, transforms composed). A definition's objects are never taken where they are stored.
    ``refused`` is why an object placed through a transform that is not read cannot be used, else None: the
    reader raises it if it takes that object (:func:`_taken`).
    """
    objects = list(f.Objects)
    by_id = {str(o.Attributes.Id): (i, o) for i, o in enumerate(objects)}
    idefs = {str(d.Id): d for d in f.InstanceDefinitions}
    out = []

    def place(top, i, ref, M, chain, refused):
        # top: the top-level placement's index; chain: the blocks this one is nested in, outermost first
        idef = idefs.get(str(ref.ParentIdefId))
        label = f"object {i} (a block placement{f' in block {chain[-1]!r}' if chain else ''})"
        if idef is None:
            raise InputError(f"{path}: {label} places a block definition that is not in the file")
        name = idef.Name
        if name in chain:
            raise InputError(f"{path}: block {name!r} contains itself")
        X, why = _xform(path, ref, f"{label} of block {name!r}")
        M, refused = (X if M is None else M @ X), refused or why
        where = f"in block {name!r} ({''.join(f'in block {c!r}, ' for c in reversed(chain))}placed by object {top})"
        ids = [str(oid) for oid in idef.GetObjectIds()]
        if idef.UpdateType.name == "Linked" or any(oid not in by_id for oid in ids):
            # its geometry lives in another file: reading the placement as empty would drop it without a word
            raise InputError(f"{path}: block {name!r} (placed by object {top}) is linked to a file whose objects are "
                             "not stored here: in Rhino, make it embedded (BlockManager) and save again")
        for oid in ids:
            j, o = by_id[oid]
            if isinstance(o.Geometry, rhino3dm.InstanceReference):
                place(top, j, o.Geometry, M, chain + (name,), refused)
            else:
                out.append((f"object {j} {where}", o.Geometry, int(o.Attributes.LayerIndex), M, refused))

    for i, o in enumerate(objects):
        if o.Attributes.IsInstanceDefinitionObject:  # a block's geometry: only where a placement puts it
            continue
        g = o.Geometry
        if isinstance(g, rhino3dm.InstanceReference):
            place(i, i, g, None, (), None)
        else:
            out.append((f"object {i}", g, int(o.Attributes.LayerIndex), None, None))
    return out


def _taken(refused: str | None) -> None:
    """An object placed by :func:`_placed` is used: refuse it if its placement cannot be read."""
    if refused:
        raise InputError(refused)


def _apply(M, P: np.ndarray) -> np.ndarray:
    """Points ``P`` (k, 3) through the placement ``M`` (None: as they are)."""
    return P if M is None else P @ M[:3, :3].T + M[:3, 3]


def _curve_points(rhino3dm, g, sample, where: str) -> np.ndarray:
    """The vertices (k, 3) of a line or polyline curve, or ``sample`` + 1 points along a curved one."""
    pl = g.TryGetPolyline()
    if pl is not None:
        return np.array([[pl[i].X, pl[i].Y, pl[i].Z] for i in range(pl.Count)], float)
    if not g.IsValid:  # not a polyline because it is no curve at all: say that, not "curved"
        s, e = g.PointAtStart, g.PointAtEnd
        if not np.isfinite([s.X, s.Y, s.Z, e.X, e.Y, e.Z]).all():
            raise InputError(f"{where} has non-finite coordinates")
        raise InputError(f"{where} is not a valid curve (a line of zero length?)")
    if not sample:
        raise InputError(f"{where} is curved: a design is made of lines and polylines "
                         "(give --sample N to replace each curve by N straight segments)")
    t0, t1 = g.Domain.T0, g.Domain.T1
    pts = [g.PointAt(t) for t in np.linspace(t0, t1, int(sample) + 1)]
    return np.array([[p.X, p.Y, p.Z] for p in pts], float)


def read_3dm_design(path, layer: str | None = None, sample: int | None = None) -> Design:
    """The design drawn in a ``.3dm`` file, in millimetres.

    Parameters
    ----------
    path : str or PathLike
    layer : str, optional
        The layer to read (its full path or name). Default: the one layer holding curves.
    sample : int, optional
        Replace each curved curve by this many straight segments (default: refuse curved curves).

    Returns
    -------
    Design
        With ``note`` saying which units the file was in and the conversion.
    """
    path = os.fspath(path)
    layer = _DEFAULTS["layer"] if layer is None else layer
    sample = _DEFAULTS["sample"] if sample is None else sample
    if sample is not None and not 1 <= sample <= MAX_SAMPLE:
        raise InputError(f"--sample must be from 1 to {MAX_SAMPLE} segments per curve, got {sample}")
    rhino3dm, f = _open(path)
    units, to_mm = _units(path, f)
    tol = float(f.Settings.ModelAbsoluteTolerance) or 1e-6
    names = _layer_names(f)
    by_layer: dict[int, list] = {}
    for label, g, li, M, refused in _placed(rhino3dm, path, f):
        if isinstance(g, rhino3dm.Curve):
            by_layer.setdefault(li, []).append((label, g, M, refused))
    if layer is None:
        if not by_layer:
            raise InputError(f"{path}: no lines or polylines in the file")
        if len(by_layer) > 1:
            held = ", ".join(repr(names[k]) if 0 <= k < len(names) else "(no layer)" for k in sorted(by_layer))
            raise InputError(f"{path}: curves on several layers ({held}): pick one with --layer")
        chosen = next(iter(by_layer))
    else:
        chosen = _pick_layer(path, names, layer)
        if chosen not in by_layer:
            raise InputError(f"{path}: layer {layer!r} holds no lines or polylines")
    layer_name = names[chosen] if 0 <= chosen < len(names) else "(no layer)"
    points, owner, edges = [], [], []
    for label, g, M, refused in by_layer[chosen]:
        _taken(refused)
        pts = _apply(M, _curve_points(rhino3dm, g, sample, f"{path}: {label} on layer {layer_name!r}"))
        base = len(points)
        points.extend(pts.tolist())
        owner.extend([label] * len(pts))
        edges.extend([(base + a, base + a + 1) for a in range(len(pts) - 1)])
    P = np.asarray(points, float)
    if not np.all(np.isfinite(P)):
        raise InputError(f"{path}: a curve on layer {layer_name!r} has non-finite coordinates")
    V, index = _snap(P, tol)
    E = index[np.asarray(edges, np.int64)]
    keep = E[:, 0] != E[:, 1]
    if not np.all(keep):  # a segment shorter than the tolerance: refuse rather than drop it silently
        s = int(np.flatnonzero(~keep)[0])
        raise InputError(f"{path}: {owner[edges[s][0]]} on layer {layer_name!r} has a segment shorter than "
                         f"the file's tolerance ({tol:g} {units.lower()})")
    _check_near_misses(path, V, E, owner, index, tol, units)
    d = design_from_arrays(V * to_mm, E, source=path)
    return dataclasses.replace(d, note=_note(path, layer_name, units, to_mm))


def _note(path, layer_name: str, units: str, to_mm: float) -> str:
    """How a file was read: its layer, its units and the conversion to mm (printed, and kept in result.json)."""
    return (f"{os.path.basename(path)}: layer {layer_name!r}, units {units}"
            + ("" if to_mm == 1.0 else f", converted to mm (x{to_mm:g})"))


def _snap(P: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge points within ``tol`` of each other (transitively); returns the merged points and each point's index."""
    from scipy.spatial import cKDTree

    parent = np.arange(len(P))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in cKDTree(P).query_pairs(tol):
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([root(i) for i in range(len(P))])
    uniq, index = np.unique(roots, return_inverse=True)
    V = np.array([P[roots == r].mean(axis=0) for r in uniq])
    return V, index


def _check_near_misses(path, V, E, owner, index, tol, units) -> None:
    from scipy.spatial import cKDTree

    valence = np.bincount(E.ravel(), minlength=len(V))
    ends = np.flatnonzero(valence == 1)
    if not len(ends):
        return
    window = NEAR_MISS * float(np.median(np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)))
    if window <= tol:  # all that close has snapped already
        return
    tree = cKDTree(V)
    for v in ends.tolist():
        neighbours = set(E[(E == v).any(axis=1)].ravel().tolist())
        near = [u for u in tree.query_ball_point(V[v], window) if u not in neighbours]
        if near:
            u = min(near, key=lambda w: np.linalg.norm(V[w] - V[v]))
            gap = float(np.linalg.norm(V[u] - V[v]))
            obj = owner[int(np.flatnonzero(index == v)[0])]
            x, y, z = V[v]
            unit = units.lower()
            raise InputError(f"{path}: the end of {obj} at ({x:g}, {y:g}, {z:g}) misses a vertex by {gap:.3g} {unit}, "
                             f"more than the file's tolerance {tol:g}: join them in Rhino (or set the tolerance above "
                             f"{gap:.3g} {unit}), or, for a free end, keep it at least {window:.3g} {unit} "
                             f"({NEAR_MISS:.0%} of the median segment) from other vertices")


def read_3dm_surface(path, layer: str | None = None, *, with_note: bool = False):
    """A target surface from a ``.3dm``: its mesh objects, or the render meshes stored with its Breps and
    extrusions (block placements included, moved where they are placed), welded within the file's tolerance
    and converted to millimetres.

    Parameters
    ----------
    path : str or PathLike
    layer : str, optional
        The layer to read (its full path or name). Default: the CLI's ``--target-layer``, else the one layer
        holding surfaces.

    with_note : bool
        Return also how the file was read (its layer, units and the conversion to mm), as a design's ``note``.

    Returns
    -------
    V : (n, 3) float, mm
    F : (t, 3) int64 (quads split into two triangles)
    note : str (with ``with_note``)
    """
    path = os.fspath(path)
    layer = _DEFAULTS["target_layer"] if layer is None else layer
    rhino3dm, f = _open(path)
    units, to_mm = _units(path, f)
    tol = float(f.Settings.ModelAbsoluteTolerance) or 1e-6
    names = _layer_names(f)
    chosen = None if layer is None else _pick_layer(path, names, layer)
    pieces, unmeshed = [], []
    for label, g, li, M, refused in _placed(rhino3dm, path, f):
        if chosen is not None and li != chosen:
            continue
        if isinstance(g, (rhino3dm.Mesh, rhino3dm.Brep, rhino3dm.Extrusion, rhino3dm.Surface, rhino3dm.SubD)):
            _taken(refused)
        lname = names[li] if 0 <= li < len(names) else "(no layer)"
        if isinstance(g, rhino3dm.Mesh):
            pieces.append((lname, g, M))
        elif isinstance(g, rhino3dm.Brep):
            meshes = [face.GetMesh(rhino3dm.MeshType.Any) for face in g.Faces]
            if any(m is None for m in meshes):
                unmeshed.append(label)
            pieces.extend((lname, m, M) for m in meshes if m is not None)
        elif isinstance(g, rhino3dm.Extrusion):
            m = g.GetMesh(rhino3dm.MeshType.Any)
            if m is None:
                unmeshed.append(label)
            else:
                pieces.append((lname, m, M))
        elif isinstance(g, (rhino3dm.Surface, rhino3dm.SubD)):  # never stored with a mesh that rhino3dm reads
            raise InputError(f"{path}: {label} is a {type(g).__name__}, which carries no mesh: in Rhino, run Mesh on "
                             "it and save the mesh, or export the surface as a mesh")
    if unmeshed:  # even beside meshes: the surface would be read with a hole where it is
        raise InputError(f"{path}: {unmeshed[0]} is a surface saved without its render mesh: in Rhino, "
                         "shade a view (or run Mesh) and save again, or export the surface as a mesh")
    if not pieces:
        raise InputError(f"{path}: no mesh, Brep or extrusion to use as the target surface"
                         + (f" on layer {layer!r}" if layer is not None else ""))
    held = sorted({name for name, _, _ in pieces})
    if layer is None and len(held) > 1:
        raise InputError(f"{path}: surfaces on several layers ({', '.join(repr(n) for n in held)}): "
                         "pick one with --target-layer")
    V, F = [], []
    for _, m, M in pieces:
        base = len(V)
        # double precision: a mesh far from the origin (map coordinates) lost vertices in single precision
        P = np.array([[p.X, p.Y, p.Z] for p in m.Vertices.ToPoint3dArray()], float).reshape(-1, 3)
        V.extend(_apply(M, P).tolist())
        mirrored = M is not None and np.linalg.det(M[:3, :3]) < 0  # keep the faces' normals where Rhino shows them
        for k in range(m.Faces.Count):
            a, b, c, d = m.Faces[k]
            tris = [(a, b, c)] + ([(a, c, d)] if d != c else [])  # a quad: two triangles
            F.extend([base + t[0], base + t[2], base + t[1]] if mirrored else [base + i for i in t] for t in tris)
    if not V or not F:  # an empty mesh: the snap below failed on its (0,) arrays
        raise InputError(f"{path}: the surface's mesh has no {'vertices' if not V else 'faces'}")
    V, index = _snap(np.asarray(V, float), tol)
    F = index[np.asarray(F, np.int64)]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
    if not with_note:
        return V * to_mm, F
    return V * to_mm, F, _note(path, held[0], units, to_mm)
