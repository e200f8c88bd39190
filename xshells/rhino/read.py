"""Reading a design from a Rhino ``.3dm`` file.

A design is the lines and polylines of one layer: each polyline vertex is a
joint or a free end, and consecutive vertices are joined by a segment.
Points closer than the file's absolute tolerance are the same vertex, so
curves drawn end to end join. An end that misses another curve by more than
the tolerance but less than ``NEAR_MISS`` tolerances is refused, with where
it is: that is a join drawn a little off, not a free end. A curved curve is
refused unless ``sample`` asks for it to be replaced by that many straight
segments. Coordinates are converted from the file's unit system to
millimetres (the note says so).
"""
from __future__ import annotations

import dataclasses
import os

import numpy as np

from ..errors import InputError, check_input_file
from ..io.design import Design, design_from_arrays

RHINO_UNITS_TO_MM = {"Millimeters": 1.0, "Centimeters": 10.0, "Decimeters": 100.0, "Meters": 1000.0,
                     "Kilometers": 1e6, "Microns": 1e-3, "Inches": 25.4, "Feet": 304.8, "Yards": 914.4}
NEAR_MISS = 100.0  # an end within this many tolerances of another vertex, but not within one, is a missed join
#: the most straight segments one curve is sampled into (--sample)
MAX_SAMPLE = 1000
# what ``read_design`` uses for a .3dm when not told: set by the command line's --layer and --sample
_DEFAULTS = {"layer": None, "sample": None}


def set_defaults(layer: str | None = None, sample: int | None = None) -> None:
    """The layer and sampling that :func:`xshells.io.read_design` uses for ``.3dm`` designs (the CLI's options)."""
    if sample is not None and not 1 <= sample <= MAX_SAMPLE:
        # each sample is a beam segment: 1e9 of them filled 24 GB before anything was said
        raise InputError(f"--sample must be from 1 to {MAX_SAMPLE} segments per curve, got {sample}")
    _DEFAULTS.update(layer=layer, sample=sample)


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


def _layer_names(f) -> list[str]:
    return [layer.FullPath or layer.Name for layer in f.Layers]


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
    curves = [(i, o) for i, o in enumerate(f.Objects) if isinstance(o.Geometry, rhino3dm.Curve)]
    by_layer: dict[int, list] = {}
    for i, o in curves:
        by_layer.setdefault(int(o.Attributes.LayerIndex), []).append((i, o.Geometry))
    if layer is None:
        if not by_layer:
            raise InputError(f"{path}: no lines or polylines in the file")
        if len(by_layer) > 1:
            held = ", ".join(repr(names[k]) if 0 <= k < len(names) else "(no layer)" for k in sorted(by_layer))
            raise InputError(f"{path}: curves on several layers ({held}): pick one with --layer")
        chosen = next(iter(by_layer))
    else:
        matches = [k for k, n in enumerate(names) if n == layer or n.split("::")[-1] == layer]
        if not matches:
            raise InputError(f"{path}: no layer {layer!r} (layers: {', '.join(repr(n) for n in names) or 'none'})")
        chosen = matches[0]
        if chosen not in by_layer:
            raise InputError(f"{path}: layer {layer!r} holds no lines or polylines")
    layer_name = names[chosen] if 0 <= chosen < len(names) else "(no layer)"
    points, owner, edges = [], [], []
    for i, g in by_layer[chosen]:
        pts = _curve_points(rhino3dm, g, sample, f"{path}: object {i} on layer {layer_name!r}")
        base = len(points)
        points.extend(pts.tolist())
        owner.extend([i] * len(pts))
        edges.extend([(base + a, base + a + 1) for a in range(len(pts) - 1)])
    P = np.asarray(points, float)
    if not np.all(np.isfinite(P)):
        raise InputError(f"{path}: a curve on layer {layer_name!r} has non-finite coordinates")
    V, index = _snap(P, tol)
    E = index[np.asarray(edges, np.int64)]
    keep = E[:, 0] != E[:, 1]
    if not np.all(keep):  # a segment shorter than the tolerance: refuse rather than drop it silently
        s = int(np.flatnonzero(~keep)[0])
        raise InputError(f"{path}: object {owner[edges[s][0]]} on layer {layer_name!r} has a segment shorter than "
                         f"the file's tolerance ({tol:g} {units.lower()})")
    _check_near_misses(path, V, E, owner, index, tol, units)
    note = (f"{os.path.basename(path)}: layer {layer_name!r}, units {units}"
            + ("" if to_mm == 1.0 else f", converted to mm (x{to_mm:g})"))
    d = design_from_arrays(V * to_mm, E, source=path)
    return dataclasses.replace(d, note=note)


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
    tree = cKDTree(V)
    for v in ends.tolist():
        neighbours = set(E[(E == v).any(axis=1)].ravel().tolist())
        near = [u for u in tree.query_ball_point(V[v], NEAR_MISS * tol) if u not in neighbours]
        if near:
            u = min(near, key=lambda w: np.linalg.norm(V[w] - V[v]))
            gap = float(np.linalg.norm(V[u] - V[v]))
            obj = owner[int(np.flatnonzero(index == v)[0])]
            x, y, z = V[v]
            raise InputError(f"{path}: the end of object {obj} at ({x:g}, {y:g}, {z:g}) misses a vertex by {gap:.3g} "
                             f"{units.lower()}, more than the file's tolerance {tol:g}: join them in Rhino, or raise the "
                             "tolerance")


def read_3dm_surface(path, layer: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A target surface from a ``.3dm``: its mesh objects, or the render meshes stored with its Breps and
    extrusions, welded within the file's tolerance and converted to millimetres.

    Returns
    -------
    V : (n, 3) float, mm
    F : (t, 3) int64 (quads split into two triangles)
    """
    path = os.fspath(path)
    layer = _DEFAULTS["layer"] if layer is None else layer
    rhino3dm, f = _open(path)
    units, to_mm = _units(path, f)
    tol = float(f.Settings.ModelAbsoluteTolerance) or 1e-6
    names = _layer_names(f)
    pieces, unmeshed = [], []
    for i, o in enumerate(f.Objects):
        g = o.Geometry
        li = int(o.Attributes.LayerIndex)
        lname = names[li] if 0 <= li < len(names) else "(no layer)"
        if layer is not None and lname != layer and lname.split("::")[-1] != layer:
            continue
        if isinstance(g, rhino3dm.Mesh):
            pieces.append((lname, g))
        elif isinstance(g, rhino3dm.Brep):
            meshes = [face.GetMesh(rhino3dm.MeshType.Any) for face in g.Faces]
            if any(m is None for m in meshes):
                unmeshed.append(i)
            pieces.extend((lname, m) for m in meshes if m is not None)
        elif isinstance(g, rhino3dm.Extrusion):
            m = g.GetMesh(rhino3dm.MeshType.Any)
            if m is None:
                unmeshed.append(i)
            else:
                pieces.append((lname, m))
    if not pieces:
        if unmeshed:
            raise InputError(f"{path}: object {unmeshed[0]} is a surface saved without its render mesh: in Rhino, "
                             "shade a view (or run Mesh) and save again, or export the surface as a mesh")
        raise InputError(f"{path}: no mesh, Brep or extrusion to use as the target surface"
                         + (f" on layer {layer!r}" if layer is not None else ""))
    held = sorted({name for name, _ in pieces})
    if layer is None and len(held) > 1:
        raise InputError(f"{path}: surfaces on several layers ({', '.join(repr(n) for n in held)}): pick one with --layer")
    V, F = [], []
    for _, m in pieces:
        base = len(V)
        V.extend([[p.X, p.Y, p.Z] for p in (m.Vertices[k] for k in range(len(m.Vertices)))])
        for k in range(m.Faces.Count):
            a, b, c, d = m.Faces[k]
            F.append([base + a, base + b, base + c])
            if d != c:  # a quad
                F.append([base + a, base + c, base + d])
    if not V or not F:  # an empty mesh: the snap below failed on its (0,) arrays
        raise InputError(f"{path}: the surface's mesh has no {'vertices' if not V else 'faces'}")
    V, index = _snap(np.asarray(V, float), tol)
    F = index[np.asarray(F, np.int64)]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
    return V * to_mm, F
