"""The X-shell linkage in reduced variables (paper §3, Fig. 3).

Every beam segment between joints (or between a joint and a free end) is a
discrete elastic rod of ``k`` edges (``subdivision``). The reduced variables
``x`` are

* 9 per joint, ``[p (3), ω (3), α, ℓA, ℓB]`` (see :mod:`.joints`), in the
  input file's vertex order;
* then, segment by segment, the positions of the rod vertices and the
  material angles that no joint controls (interior ones and free ends).

A joint controls the two vertices and the material angle of the terminal
edge of each rod that meets it; two rods that continue each other through a
joint both hold that edge, so each copy gets half its stretching stiffness
and half its mass.

The design parameters ``p`` are one rest length per segment. A segment's
rest length counts half of each terminal edge it shares with a joint; the
joint edge's rest length is set by the segment of the beam with the
shorter ideal edge (chosen once, at construction, so that the map stays
linear), and the rest is spread evenly over the segment's other edges. A
straight flat beam at the rest lengths of its segments therefore has zero
energy.

Cross-section orientation: at a joint the rod's ``m2`` is the joint normal
(the layout's normal in the flat state) and ``m1 = n × t`` lies in the
layout plane. With :mod:`xshells.section` conventions (``x`` along ``m1``)
a rectangle's first dimension lies in the layout plane and its second
along the normal, so flat beams bend out of plane most easily.
``section_angle`` rotates the cross-section about the beam.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import InputError, InvalidState
from ..io.design import Design
from ..rod import ElasticRods
from ..rod import frames, vec
from ..rod import rods as _rods_module
from ..sparse import VectorAssembler
from . import joint_kernels as jk
from . import joints as jmap
from .graph import BEAM_A, INCOMING, OUTGOING, LinkageGraph, analyze


class Linkage:
    """An X-shell: rods coupled at joints, with energy and derivatives in reduced variables.

    Parameters
    ----------
    design : Design
        Joint and free-end positions and the segments between them.
    material : xshells.section.Material, or a sequence of them (one per segment)
    subdivision : int
        Edges per segment (k ≥ 3).
    rest_lengths : (S,) array, optional
        Per-segment rest lengths; default: the straight distances in the design.
    section_angle : float
        Rotation of the cross-section about the beam, radians.
    bending_energy : {"2008", "2010"}
    """

    def __init__(self, design: Design, material, *, subdivision: int = 10, rest_lengths=None,
                 section_angle: float = 0.0, bending_energy: str = "2008", graph: LinkageGraph | None = None):
        if subdivision < 3:
            raise InputError(f"subdivision must be at least 3 edges per segment, got {subdivision}")
        self.design = design
        self.graph = g = graph if graph is not None else analyze(design)
        self.subdivision = k = int(subdivision)
        V = np.asarray(design.vertices, float)
        E = np.asarray(design.edges)
        S, nj = g.num_segments, g.num_joints
        self.num_segments, self.num_joints = S, nj
        self.section_angle = float(section_angle)

        chord = np.linalg.norm(V[E[:, 1]] - V[E[:, 0]], axis=1)
        p = chord.copy() if rest_lengths is None else np.asarray(rest_lengths, float)
        if p.shape != (S,):
            raise InputError(f"rest lengths: expected {S} values (one per segment), got {p.size}")
        bad = np.flatnonzero(~(np.isfinite(p) & (p > 0)))
        if len(bad):
            raise InputError(f"{design.label()}: {design.where_edge(int(bad[0]))}: rest length {p[bad[0]]} is not positive "
                             "and finite")

        # ---- per segment end: joint, beam, slot, orientation, partner segment
        ends = []  # (segment, end 0/1, joint, beam, sigma, partner)
        for s in range(S):
            for e in (0, 1):
                J = int(g.segment_joints[s, e])
                if J < 0:
                    continue
                X = int(g.segment_labels[s, e])
                slots = g.joint_segments[J, X]
                slot = INCOMING if slots[INCOMING] == s and (slots[OUTGOING] != s or e == 1) else OUTGOING
                sigma = 1.0 if (e == 0 and slot == OUTGOING) or (e == 1 and slot == INCOMING) else -1.0
                partner = int(slots[1 - slot])
                ends.append((s, e, J, X, sigma, partner))
        self._ends = ends
        joint_ends = np.zeros((S, 2), bool)
        for s, e, *_ in ends:
            joint_ends[s, e] = True
        n_joint = joint_ends.sum(axis=1)
        n_int = k - n_joint
        c = n_int + 0.5 * n_joint  # effective edge count of the segment's rest length
        ideal = p / c

        # ---- rest-length map W: edge rest lengths = W p
        rows, cols, vals = [], [], []
        controller = {}
        for s, e, J, X, sigma, partner in ends:
            ctrl = s if partner < 0 or ideal[s] <= ideal[partner] else partner
            if partner >= 0 and ideal[s] == ideal[partner]:
                ctrl = min(s, partner)
            controller[(s, e)] = ctrl
        edge_of = lambda s, i: s * k + i  # noqa: E731
        for s in range(S):
            interior = [i for i in range(k) if not ((i == 0 and joint_ends[s, 0]) or (i == k - 1 and joint_ends[s, 1]))]
            for i in interior:
                rows.append(edge_of(s, i)); cols.append(s); vals.append(1.0 / n_int[s])
            for e in (0, 1):
                if not joint_ends[s, e]:
                    continue
                ctrl = controller[(s, e)]
                i = 0 if e == 0 else k - 1
                rows.append(edge_of(s, i)); cols.append(ctrl); vals.append(1.0 / c[ctrl])
                for ii in interior:
                    rows.append(edge_of(s, ii)); cols.append(ctrl); vals.append(-0.5 / c[ctrl] / n_int[s])
        self.rest_length_map = sp.csr_matrix((vals, (rows, cols)), shape=(S * k, S))
        edge_rest = self.rest_length_map @ p
        if (edge_rest <= 0).any():
            bad = int(np.flatnonzero(edge_rest <= 0)[0]) // k
            raise InputError(f"{design.label()}: {design.where_edge(bad)}: rest length {p[bad]:.6g} too short for its "
                             f"joint edges at subdivision {k}")

        # ---- joints: initial variables and source frames
        t = g.joint_tangents
        alpha = np.arccos(np.clip(np.sum(t[:, 0] * t[:, 1], axis=1), -1.0, 1.0))
        bad = np.flatnonzero((alpha < 1e-6) | (alpha > np.pi - 1e-6))
        if len(bad):
            # alpha is 0° or 180° by how the beams happen to be oriented: name the angle they cross at instead,
            # the same for both (the message said "0°" for one straight polyline and "180°" for another)
            j = int(bad[0])
            jv = int(g.joint_vertex[j])
            cross = np.degrees(min(alpha[j], np.pi - alpha[j]))
            hint = ("; a node of valence 2 is a hinge between two beams that end there, not a point along one "
                    "beam: draw a straight beam through it as one segment") if g.valence[jv] == 2 else ""
            raise InputError(f"{design.label()}: {design.where_vertex(jv)}: the joint's two beams are parallel "
                             f"(they cross at {cross:.2g}°){hint}")
        b0 = t[:, 0] + t[:, 1]
        b0 /= np.linalg.norm(b0, axis=1)[:, None]
        n0 = np.asarray(g.joint_normals, float).copy()
        joint_edge_rest = np.zeros((nj, 2))
        for s, e, J, X, sigma, partner in ends:
            joint_edge_rest[J, X] = edge_rest[edge_of(s, 0 if e == 0 else k - 1)]
        self.joint_b0, self.joint_n0 = b0, n0
        xj = np.zeros((nj, 9))
        xj[:, 0:3] = V[g.joint_vertex]
        xj[:, 6] = alpha
        xj[:, 7:9] = joint_edge_rest
        tA, tB, _ = (np.stack(a, 1) for a in jmap.joint_frame(tuple(xj.T), tuple(b0.T), tuple(n0.T)))
        if not (np.allclose(tA, t[:, 0], atol=1e-9) and np.allclose(tB, t[:, 1], atol=1e-9)):
            raise AssertionError("joint frame does not reproduce the graph's beam tangents")

        # ---- rods: initial geometry
        rod_points = []
        for s in range(S):
            pts = np.zeros((k + 1, 3))
            front, back = 0, k
            for s2, e, J, X, sigma, partner in ends:
                if s2 != s:
                    continue
                half = 0.5 * sigma * joint_edge_rest[J, X] * (tA[J] if X == BEAM_A else tB[J])
                if e == 0:
                    pts[0], pts[1] = V[g.joint_vertex[J]] - half, V[g.joint_vertex[J]] + half
                    front = 1
                else:
                    pts[k - 1], pts[k] = V[g.joint_vertex[J]] - half, V[g.joint_vertex[J]] + half
                    back = k - 1
            if front == 0:
                pts[0] = V[E[s, 0]]
            if back == k:
                pts[k] = V[E[s, 1]]
            w = np.linspace(0.0, 1.0, back - front + 1)[:, None]
            pts[front : back + 1] = (1 - w) * pts[front] + w * pts[back]
            rod_points.append(pts)

        # material per edge, halving shared joint edges
        from ..section import expand_materials

        mats = material if isinstance(material, (list, tuple)) else [material]
        props = expand_materials(material, [k] * S)
        polar = np.array([float(np.trace(np.asarray(m.second_moments))) for m in mats])
        polar = np.full(S * k, polar[0]) if len(mats) == 1 else np.repeat(polar, k)
        shared = np.ones(S * k)
        for s, e, J, X, sigma, partner in ends:
            if partner >= 0:
                shared[edge_of(s, 0 if e == 0 else k - 1)] = 0.5
        self.materials = mats
        directors = []
        for s in range(S):
            d = rod_points[s][1] - rod_points[s][0]
            tt = d / np.linalg.norm(d)
            directors.append(frames.perpendicular(tt[None, :])[0])
        # the first edge's director follows the joint's m1 when the segment starts at a joint
        first_end = {s: (J, X, sigma) for s, e, J, X, sigma, partner in ends if e == 0}
        for s, (J, X, sigma) in first_end.items():
            te = sigma * (tA[J] if X == BEAM_A else tB[J])
            m1 = np.cos(self.section_angle) * np.cross(n0[J], te) - np.sin(self.section_angle) * n0[J]
            directors[s] = m1
        self.rods = ElasticRods(
            rod_points,
            stretching=props["ks"] * shared,
            bending=np.stack([props["B1"], props["B2"]], axis=1),
            twisting=props["kt"],
            area=props["area"],
            density=props["density"] * shared,
            polar_moment=polar,
            rest_lengths=edge_rest,
            directors=directors,
            bending_energy=bending_energy,
        )
        self._p = p.copy()

        # ---- variable bookkeeping
        nv = self.rods.num_vars
        V3 = 3 * self.rods.num_vertices
        controlled = np.zeros(nv, bool)
        inst_rows = np.zeros((7, len(ends)), np.int64)
        inst_joint = np.zeros(len(ends), np.int64)
        inst_prm = np.zeros((jmap.NUM_INSTANCE_PARAMS, len(ends)))
        for i, (s, e, J, X, sigma, partner) in enumerate(ends):
            edge = edge_of(s, 0 if e == 0 else k - 1)
            v0, v1 = self.rods.edges[edge]
            inst_rows[0:3, i] = 3 * v0 + np.arange(3)
            inst_rows[3:6, i] = 3 * v1 + np.arange(3)
            inst_rows[6, i] = V3 + edge
            inst_joint[i] = J
            inst_prm[6, i] = float(X)
            inst_prm[7, i] = sigma
            inst_prm[15, i] = self.section_angle
        controlled[inst_rows.ravel()] = True
        self._inst_rows, self._inst_joint, self._inst_prm = inst_rows, inst_joint, inst_prm
        self._inst_edge = inst_rows[6] - V3
        free_rod = np.flatnonzero(~controlled)
        # order free variables segment by segment: positions then angles of each segment
        seg_of_var = np.concatenate([np.repeat(np.arange(S), 3 * (k + 1)), np.repeat(np.arange(S), k)])
        kind = np.concatenate([np.zeros(V3), np.ones(nv - V3)])
        order = np.lexsort((kind[free_rod], seg_of_var[free_rod]))
        self._free_rod = free_rod[order]
        self.num_joint_vars = 9 * nj
        self._free_reduced = self.num_joint_vars + np.arange(len(self._free_rod))
        self.num_vars = self.num_joint_vars + len(self._free_rod)

        x = np.zeros(self.num_vars)
        x[: self.num_joint_vars] = xj.ravel()
        x[self._free_reduced] = self.rods.get_vars()[self._free_rod]
        self._x = x
        self._refresh_instance_sources(theta_prev=np.zeros(len(ends)))
        # terminal angles from the joints; spread each rod's end-to-end twist over its interior angles
        out = jk.outputs(self._instance_q(x), self._inst_prm)
        self._refresh_instance_sources(theta_prev=out[6])
        rod_v = self.rods.get_vars()
        rod_v[inst_rows[6]] = out[6]
        for s in range(S):
            if joint_ends[s, 1]:
                th_last = rod_v[V3 + edge_of(s, k - 1)]
                th_first = rod_v[V3 + edge_of(s, 0)]
                ramp = np.linspace(th_first, th_last, k)
                idx = V3 + edge_of(s, 0) + np.arange(1, k - 1)
                rod_v[idx] = ramp[1:-1]
        x[self._free_reduced] = rod_v[self._free_rod]
        self.set_vars(x)
        self.rods.update_source_frame()
        self._refresh_instance_sources(theta_prev=self._instance_outputs()[6])

    # ------------------------------------------------------------ bookkeeping
    def _refresh_instance_sources(self, theta_prev):
        e = self._inst_edge
        J = self._inst_joint
        self._inst_prm[0:3] = self.joint_b0[J].T
        self._inst_prm[3:6] = self.joint_n0[J].T
        self._inst_prm[8:11] = self.rods.t_src[e].T
        self._inst_prm[11:14] = self.rods.d1_src[e].T
        self._inst_prm[14] = theta_prev

    def _instance_q(self, x):
        xj = x[: self.num_joint_vars].reshape(-1, 9)
        return np.ascontiguousarray(xj[self._inst_joint].T)

    def _instance_outputs(self):
        return jk.outputs(self._instance_q(self._x), self._inst_prm)

    def rod_vars(self, x=None) -> np.ndarray:
        """The rods' variables (positions and angles) for reduced variables ``x``."""
        x = self._x if x is None else x
        v = np.empty(self.rods.num_vars)
        v[self._free_rod] = x[self._free_reduced]
        out = jk.outputs(self._instance_q(x), self._inst_prm)
        v[self._inst_rows] = out
        return v

    # -------------------------------------------------------------- variables
    def get_vars(self) -> np.ndarray:
        return self._x.copy()

    def set_vars(self, x) -> None:
        x = np.asarray(x, float)
        if x.shape != (self.num_vars,):
            raise InputError(f"expected {self.num_vars} reduced variables, got shape {x.shape}")
        if not np.isfinite(x).all():
            raise InvalidState(f"reduced variable {int(np.flatnonzero(~np.isfinite(x))[0])} is not finite")
        self.rods.set_vars(self.rod_vars(x))
        self._x = x.copy()

    @property
    def rest_lengths(self) -> np.ndarray:
        """Per-segment rest lengths ``p``, (S,)."""
        return self._p.copy()

    def set_rest_lengths(self, p) -> None:
        p = np.asarray(p, float)
        if p.shape != (self.num_segments,):
            raise InputError(f"rest lengths: expected {self.num_segments} values, got shape {p.shape}")
        edge = self.rest_length_map @ p
        if not (np.isfinite(edge).all() and (edge > 0).all()):
            s = int(np.flatnonzero(~(edge > 0))[0]) // self.subdivision
            raise InvalidState(f"rest lengths: {_segment_at(self.design, s)} would get a non-positive edge rest length")
        self.rods.set_rest_lengths(edge)
        self._p = p.copy()

    def move_checkpoint(self):
        """A cheap checkpoint before temporary moves of ``x`` or ``p`` (e.g. finite differences).

        :meth:`set_vars` and :meth:`set_rest_lengths` replace their arrays
        rather than write into them, so references suffice; the cached
        evaluations at the state are kept too. Frames are not covered: do
        not call :meth:`update_source_frame` between checkpoint and rollback.
        """
        r = self.rods
        return self._x, self._p, r.points, r.thetas, r.rest_lengths, getattr(self, "_cache", None)

    def move_rollback(self, checkpoint) -> None:
        """Back to a :meth:`move_checkpoint`, bit for bit, cached evaluations included."""
        r = self.rods
        self._x, self._p, r.points, r.thetas, r.rest_lengths, cache = checkpoint
        if cache is not None:
            self._cache = cache

    def update_source_frame(self) -> None:
        """Fold the joint rotations into the source frames (ω ← 0) and update the rods' frames."""
        xj = self._x[: self.num_joint_vars].reshape(-1, 9)
        w = xj[:, 3:6]
        self.joint_b0 = _rotate(w, self.joint_b0)
        self.joint_n0 = _rotate(w, self.joint_n0)
        # re-orthonormalize against drift
        self.joint_b0 /= np.linalg.norm(self.joint_b0, axis=1)[:, None]
        self.joint_n0 -= np.sum(self.joint_n0 * self.joint_b0, 1)[:, None] * self.joint_b0
        self.joint_n0 /= np.linalg.norm(self.joint_n0, axis=1)[:, None]
        theta = self.rods.thetas[self._inst_edge].copy()
        xj[:, 3:6] = 0.0
        _update_rod_source_frame(self.rods)
        self._refresh_instance_sources(theta_prev=theta)

    def apply_rigid_motion(self, R, t) -> None:
        """Move the whole state rigidly, every point ``y ↦ R y + t`` (``R`` a proper rotation, (3, 3); ``t`` (3,)).

        Positions move and every frame (joints' and rods' source frames)
        turns with the body, so material angles, opening angles and edge
        lengths stay: energy and stability are unchanged, the gradient turns
        with ``R``.
        """
        R, t = np.asarray(R, float), np.asarray(t, float)
        self.update_source_frame()  # ω = 0: each joint's frame is its source frame
        x = self.get_vars()
        xj = x[: self.num_joint_vars].reshape(-1, 9)
        xj[:, 0:3] = xj[:, 0:3] @ R.T + t
        moved = self.rods.points @ R.T + t
        rod = self._free_rod
        pos = rod < 3 * self.rods.num_vertices
        x[self._free_reduced[pos]] = moved[rod[pos] // 3, rod[pos] % 3]
        self.joint_b0, self.joint_n0 = self.joint_b0 @ R.T, self.joint_n0 @ R.T
        self.rods.t_src, self.rods.d1_src = self.rods.t_src @ R.T, self.rods.d1_src @ R.T
        self._refresh_instance_sources(theta_prev=self._inst_prm[14].copy())
        self.set_vars(x)

    # ---------------------------------------------------------------- energy
    # Energy, gradient and Hessian share one evaluation of the rod stencils per
    # state: a Newton iteration asks for the energy (line search), then the
    # gradient and the Hessian at the accepted point. The cache is keyed on the
    # content of everything they depend on (variables, rest lengths, frames), so
    # direct edits of the rods or the frames (e.g. a snapshot restore) are seen.
    def _state_key(self):
        r = self.rods
        return (self._x, r.points, r.thetas, r.rest_lengths, r.t_src, r.d1_src, r.ref_twist_src, r.kappa_bar, r.twist_bar,
                self._inst_prm)

    def _cached(self) -> dict:
        key = self._state_key()
        c = getattr(self, "_cache", None)
        if c is not None and all(a.shape == b.shape and (a == b).all() for a, b in zip(c["key"], key)):
            return c
        self._cache = {"key": tuple(np.array(a, copy=True) for a in key)}
        return self._cache

    # The helpers below take the cache ``c`` of the current state when their caller has it
    # (each lookup compares the whole state: 10 arrays).
    def _stencils(self, derivatives: bool = True, c=None):
        """The analytic kernels' vertex stencils at the current state (cached): one evaluation of their
        geometry serves the energy, then (completed with ``derivatives``) the gradient and the Hessian."""
        c = self._cached() if c is None else c
        s = c.get("stencils")
        if s is None:
            r = self.rods
            s = c["stencils"] = _rods_module._analytic._Stencil(r._vertex_q(), r._vertex_params(), r.bending_energy,
                                                                derivatives=derivatives)
        elif derivatives:
            s.first_derivatives()
        return s

    def _rod_energies(self, c=None) -> tuple:
        """(stretch, bend, twist) at the current state (cached); at a state whose gradient is not
        cached (a line search's trial point) the derivatives are not formed."""
        c = self._cached() if c is None else c
        if "rod" in c:
            t = c["rod"]
            return t["stretch"], t["bend"], t["twist"]
        if "energies" not in c:
            r = self.rods
            if _rods_module._analytic is None or not r.num_stencils:
                t = self._rod_terms(c)
                return t["stretch"], t["bend"], t["twist"]
            es = _rods_module.stretch_kernel(r._edge_q(), r.ks, hessian=False, gradient=False)[0]
            s = self._stencils(False, c)
            c["energies"] = (float(np.sum(es)), float(np.sum(s.bend)), float(np.sum(s.twist)))
        return c["energies"]

    def _rod_terms(self, c=None) -> dict:
        """Per-stencil rod energies and gradients at the current state (cached)."""
        c = self._cached() if c is None else c
        if "rod" not in c:
            r = self.rods
            es, ge, _ = _rods_module.stretch_kernel(r._edge_q(), r.ks, hessian=False)
            an = _rods_module._analytic
            if r.num_stencils and an is not None:
                s = self._stencils(True, c)
                bend, twist, gv = s.bend, s.twist, s.gradient()
            elif r.num_stencils:
                (bend, twist), gv = r._vertex_energies(), None
            else:
                bend, twist, gv = np.zeros(0), np.zeros(0), np.zeros((13, 0))
            self._store_rod_terms(c, es, ge, bend, twist, gv)
        return c["rod"]

    def _store_rod_terms(self, c, es, ge, bend, twist, gv) -> None:
        """Cache the rods' per-stencil energies (summed) and gradients for the state of cache ``c``."""
        c["rod"] = {"stretch": float(np.sum(es)), "ge": ge, "bend": float(np.sum(bend)),
                    "twist": float(np.sum(twist)), "gv": gv}

    def _rod_gradient(self, with_rest_lengths: bool = False, c=None) -> np.ndarray:
        c = self._cached() if c is None else c
        key = ("rod_grad", with_rest_lengths)
        if key not in c:
            t = self._rod_terms(c)
            if t["gv"] is None:
                c[key] = self.rods.gradient(with_rest_lengths)
            else:
                size = self.rods.num_vars + (self.rods.num_edges if with_rest_lengths else 0)
                c[key] = self._vector_assembler(size).assemble([t["gv"], t["ge"]])
        return c[key]

    def _vector_assembler(self, size: int) -> VectorAssembler:
        """Sums per-stencil rod vectors (vertex (13, S), edge (7, E)) into rod space of ``size``
        (rod variables, then the edges' rest lengths if ``size`` includes them); built once per size."""
        cache = self.__dict__.setdefault("_vector_assemblers", {})
        if size not in cache:
            cache[size] = VectorAssembler([self.rods.vertex_index, self.rods.edge_index], size)
        return cache[size]

    def energy_parts(self):
        return _rods_module.EnergyParts(*self._rod_energies())

    def energy(self) -> float:
        return self.energy_parts().total

    def _instance_jacobian(self, c=None):
        """Joint-map outputs (7, N) and Jacobian (7, 9, N) of every instance at the current state."""
        c = self._cached() if c is None else c
        if "jac" not in c:
            c["jac"] = jk.outputs_and_jacobian(self._instance_q(self._x), self._inst_prm)
        return c["jac"]

    def rod_jacobian(self):
        """Rod variables' Jacobian with respect to ``x``: sparse (num rod vars, num_vars)."""
        _, jac = self._instance_jacobian()
        n_inst = jac.shape[2]
        rows = np.broadcast_to(self._inst_rows[:, None, :], (7, 9, n_inst)).ravel()
        cols = np.broadcast_to((9 * self._inst_joint)[None, None, :] + np.arange(9)[None, :, None], (7, 9, n_inst)).ravel()
        r = np.concatenate([self._free_rod, rows])
        c = np.concatenate([self._free_reduced, cols])
        v = np.concatenate([np.ones(len(self._free_rod)), jac.ravel()])
        return sp.csr_matrix((v, (r, c)), shape=(self.rods.num_vars, self.num_vars))

    def gradient(self, with_rest_lengths: bool = False) -> np.ndarray:
        """``∂E/∂x`` (num_vars,), or ``[∂E/∂x, ∂E/∂p]`` with the rest lengths appended."""
        c = self._cached()
        key = ("grad", with_rest_lengths)
        if key in c:
            return c[key].copy()
        g = self._rod_gradient(with_rest_lengths, c)
        nv = self.rods.num_vars
        gx = np.zeros(self.num_vars)
        gx[self._free_reduced] = g[self._free_rod]
        _, jac = self._instance_jacobian(c)
        contrib = np.einsum("oin,on->in", jac, g[self._inst_rows])
        gx[: self.num_joint_vars] += np.bincount(
            ((9 * self._inst_joint)[None, :] + np.arange(9)[:, None]).ravel(), weights=contrib.ravel(), minlength=self.num_joint_vars
        )
        if with_rest_lengths:
            gx = np.concatenate([gx, self.rest_length_map.T @ g[nv:]])
        c[key] = gx
        return gx.copy()

    def _joint_hessian_blocks(self, c=None):
        """``∇²(g·joint_map)`` per instance, (9, 9, N), with ``g`` the rods' gradient."""
        w = self._rod_gradient(False, c)[self._inst_rows]
        return jk.weighted_hessian(self._instance_q(self._x), self._inst_prm, w)

    def _vertex_hessian_blocks(self) -> np.ndarray:
        return self.rods._vertex_hessian() if self.rods.num_stencils else np.zeros((13, 13, 0))

    def _rod_hessian_blocks(self, c=None):
        """Vertex (13, 13, S) and edge (7, 7, E) Hessian blocks at the current state.

        At a state whose rod terms are not cached yet (a Newton step's new
        state), energies, gradients and Hessians come from one evaluation of
        each stencil's geometry and fill the cache for the gradient too.
        """
        r = self.rods
        c = self._cached() if c is None else c
        an = _rods_module._analytic
        if an is None or not r.num_stencils:
            _, _, he = _rods_module.stretch_kernel(r._edge_q(), r.ks)
            return self._vertex_hessian_blocks(), he
        if "rod" in c:
            _, _, he = _rods_module.stretch_kernel(r._edge_q(), r.ks)
            return an._hessian(self._stencils(True, c))[0], he
        es, ge, he = _rods_module.stretch_kernel(r._edge_q(), r.ks)
        s = self._stencils(True, c)
        hv, gv = an._hessian(s)
        self._store_rod_terms(c, es, ge, s.bend, s.twist, gv)
        return hv, he

    def hessian(self, with_rest_lengths: bool = False) -> sp.csr_matrix:
        """Sparse symmetric Hessian in ``x`` (and ``p`` appended, if asked).

        Without the rest lengths it is assembled straight into the reduced
        variables (:class:`_ReducedHessianAssembler`, a fixed pattern); the
        returned matrix is a new object each time but shares its ``indices``
        and ``indptr`` arrays with every other call, and must not be modified
        in place.
        """
        c = self._cached()
        key = ("hess", with_rest_lengths)
        if key in c:
            return c[key]
        if not with_rest_lengths:
            H = self._reduced_assembler().assemble(*self._hessian_parts(c))
            c[key] = H
            return H
        H = self.rods.hessian(with_rest_lengths)
        J = self.rod_jacobian()
        J = sp.block_diag([J, self.rest_length_map], format="csr")
        Hx = J.T.tocsr() @ (H @ J)
        Hj = self._joint_hessian_blocks()
        n_inst = Hj.shape[2]
        base = (9 * self._inst_joint)[None, None, :]
        rows = np.broadcast_to(base + np.arange(9)[:, None, None], (9, 9, n_inst)).ravel()
        cols = np.broadcast_to(base + np.arange(9)[None, :, None], (9, 9, n_inst)).ravel()
        size = Hx.shape[0]
        H = (Hx + sp.csr_matrix((Hj.ravel(), (rows, cols)), shape=(size, size))).tocsr()
        c[key] = H
        return H

    def hessian_lower(self) -> sp.csr_matrix:
        """The lower triangle (row ≥ column) of :meth:`hessian` with the very same values: all that a
        Cholesky factorization reads, at about half the assembly (the solver's path; its eigen-solves
        take the whole :meth:`hessian`). Shares its pattern arrays across calls like :meth:`hessian`."""
        c = self._cached()
        if "hess_lower" not in c:
            asm = self._reduced_assembler()
            full = c.get(("hess", False))
            c["hess_lower"] = asm.lower_of(full) if full is not None else asm.assemble(*self._hessian_parts(c), lower=True)
        return c["hess_lower"]

    def _reduced_assembler(self) -> "_ReducedHessianAssembler":
        asm = getattr(self, "_hess_asm", None)
        if asm is None:
            asm = self._hess_asm = _ReducedHessianAssembler(self)
        return asm

    def _hessian_parts(self, c):
        """What the reduced Hessian is assembled from (cached with the state: the whole Hessian and
        its lower triangle may both be asked for at one state)."""
        if "hess_parts" not in c:
            hv, he = self._rod_hessian_blocks(c)
            _, jac = self._instance_jacobian(c)
            c["hess_parts"] = (hv, he, jac, self._joint_hessian_blocks(c))
        return c["hess_parts"]

    def mass_matrix(self) -> sp.csr_matrix:
        """``Jᵀ M J / ρ̄`` with ``M`` the rods' lumped mass and ``ρ̄`` their largest density: symmetric positive
        definite, not lumped.

        It is the solvers' metric (Hessian modification, saddle escapes, stability eigenvalues), so it is
        taken at unit (largest) density: a physical density (t/mm³, for self-weight) must not change how a
        deployment is solved. Measured: the manta ray at ρ = 1.9e-9 stalled at 62° with the unscaled mass.
        """
        J = self.rod_jacobian()
        rho = float(np.max(self.rods.density)) or 1.0
        # divided before the masses are formed: one material gives densities of exactly 1 (and ½ on shared
        # edges), so the metric is the same to the last bit whatever the density (deployments that pass
        # near a bifurcation can follow round-off)
        return self._on_mass_pattern(J, (J.T @ self.rods.mass_matrix(self.rods.density / rho) @ J).tocsr())

    def _on_mass_pattern(self, J: sp.csr_matrix, M: sp.csr_matrix) -> sp.csr_matrix:
        """``M`` (= ``Jᵀ D J``) on the structural pattern of ``JᵀJ``, explicit zeros kept.

        SciPy's sparse product drops the entries that come out exactly zero, and which do depends on the
        state (the flat state's zero heights): the metric's pattern changed from one deployment step to the
        next, and every change cost the solver a new union pattern and a new symbolic factorization of
        ``H + σM`` (manta ray at 10 steps: six of each). The pattern depends only on the linkage's topology.
        """
        pattern = getattr(self, "_mass_pattern", None)
        n = M.shape[1]
        if pattern is None:
            ones = sp.csr_matrix((np.ones(J.nnz), J.indices, J.indptr), shape=J.shape)
            P = (ones.T @ ones).tocsr()  # sums of positive terms: no entry cancels
            P.sort_indices()
            keys = np.repeat(np.arange(n, dtype=np.int64), np.diff(P.indptr)) * n + P.indices
            pattern = self._mass_pattern = (P.indices.astype(np.int32), P.indptr.astype(np.int32), keys)
        indices, indptr, keys = pattern
        M.sort_indices()
        slots = np.searchsorted(keys, np.repeat(np.arange(n, dtype=np.int64), np.diff(M.indptr)) * n + M.indices)
        data = np.zeros(len(keys))
        data[slots] = M.data
        out = sp.csr_matrix((data, indices, indptr), shape=M.shape)
        out.indices, out.indptr = indices, indptr  # the constructor may copy them: one pattern, recognisably
        out.has_canonical_format = True
        return out

    def gravity_force(self, g=(0.0, 0.0, -9810.0)) -> np.ndarray:
        """Generalized gravity force on ``x`` (``Jᵀ f`` of the rods' lumped gravity), (num_vars,).

        ``g`` in the input's units (mm/s² for the bundled designs; then
        densities in t/mm³ give forces in N).
        """
        return self.rod_jacobian().T @ self.rods.gravity_force(g)

    def joint_force(self, forces) -> np.ndarray:
        """Generalized force of point forces at the joints: ``forces`` (nj, 3) → (num_vars,)."""
        forces = np.asarray(forces, float)
        if forces.shape != (self.num_joints, 3):
            raise InputError(f"joint forces: expected shape ({self.num_joints}, 3), got {forces.shape}")
        f = np.zeros(self.num_vars)
        f[: self.num_joint_vars].reshape(-1, 9)[:, 0:3] = forces
        return f

    # ------------------------------------------------------------- selectors
    def joint_positions(self) -> np.ndarray:
        """(nj, 3) joint positions, in the input file's vertex order."""
        return self._x[: self.num_joint_vars].reshape(-1, 9)[:, 0:3].copy()

    def free_end_rod_vertex(self, v: int) -> tuple[int, int, int]:
        """(rod vertex at free-end vertex ``v``, its neighbour on the rod, the end edge): one rod per segment,
        running from ``edges[s, 0]`` to ``edges[s, 1]``."""
        E = self.graph.design.edges
        s = int(np.flatnonzero((E == v).any(axis=1))[0])
        a, b = self.rods.vertex_offsets[s], self.rods.vertex_offsets[s + 1]
        if E[s, 0] == v:
            return int(a), int(a + 1), int(self.rods.edge_offsets[s])
        return int(b - 1), int(b - 2), int(self.rods.edge_offsets[s + 1] - 1)

    def vertex_positions(self) -> np.ndarray:
        """Current positions (n, 3) of every design vertex: joints, and free ends at their rods' end points."""
        g = self.graph
        V = np.array(g.design.vertices, float)
        V[np.asarray(g.joint_vertex)] = self.joint_positions()
        for v in np.asarray(g.free_end_vertex):
            V[v] = self.rods.points[self.free_end_rod_vertex(int(v))[0]]
        return V

    def joint_angles(self) -> np.ndarray:
        """(nj,) opening angles α."""
        return self._x[6 : self.num_joint_vars : 9].copy()

    def average_angle(self) -> float:
        return float(np.mean(self.joint_angles()))

    def angle_indices(self) -> np.ndarray:
        """Indices of the joint opening angles in ``x`` (the selector S_α)."""
        return 9 * np.arange(self.num_joints) + 6

    def height_selector(self) -> sp.csr_matrix:
        """S_z: joint heights along the layout normal, sparse (nj, num_vars)."""
        nrm = np.asarray(self.graph.layout_normal, float)
        rows = np.repeat(np.arange(self.num_joints), 3)
        cols = (9 * np.arange(self.num_joints))[:, None] + np.arange(3)[None, :]
        return sp.csr_matrix((np.tile(nrm, self.num_joints), (rows, cols.ravel())), shape=(self.num_joints, self.num_vars))

    def angle_selector(self) -> sp.csr_matrix:
        """S_α as a sparse (nj, num_vars) matrix."""
        nj = self.num_joints
        return sp.csr_matrix((np.ones(nj), (np.arange(nj), self.angle_indices())), shape=(nj, self.num_vars))

    def central_joint(self) -> int:
        P = self.joint_positions()
        return int(np.argmin(np.linalg.norm(P - P.mean(axis=0), axis=1)))

    def rigid_pin_indices(self, joint: int | None = None) -> np.ndarray:
        """Indices of one joint's position and rotation (6 variables) that pin the rigid motion."""
        j = self.central_joint() if joint is None else int(joint)
        return 9 * j + np.arange(6)

    def min_arc_length(self) -> float:
        return float(np.min(self._p))

    def input_warnings(self) -> list:
        """One-line warnings about the input that explain a bad result: :meth:`slenderness_warning`,
        segments that cross without a joint, nodes of valence 2 that look like a polyline's bends (hinges
        there), and a design that is not flat (then simulated from the
        state as drawn)."""
        out = [w for w in [self.slenderness_warning(), self.graph.crossings, self.graph.bends, self.offset_warning()] if w]
        if not self.graph.is_planar:
            P = np.asarray(self.graph.design.vertices, float)
            off = float(np.abs((P - P.mean(axis=0)) @ self.graph.layout_normal).max())
            out.append(f"the design is not flat (up to {off:.4g} off its best-fit plane): it is deployed from the "
                       f"state as drawn, not from a flat assembly state")
        return out

    def offset_warning(self) -> str:
        """A one-line warning when the design lies more than :data:`FAR_FROM_ORIGIN` spans from the origin, else "".

        Coordinates that large carry fewer digits of the design itself: the same grid (184 mm across)
        deployed to the same torque to 1e-7 up to 54,000 spans from the origin, and 0.06 % off at 540,000
        (georeferenced coordinates in mm reach that). Said, not changed: the outputs stay where the input is.
        """
        P = np.asarray(self.graph.design.vertices, float)[np.unique(self.graph.design.edges)]
        centre = P.mean(axis=0)
        span = float(np.ptp(P, axis=0).max())
        far = float(np.abs(centre).max())
        if span <= 0 or far <= FAR_FROM_ORIGIN * span:
            return ""
        return (f"the design lies {far / span:.2g} spans from the origin (its centre at "
                f"({', '.join(f'{c:.6g}' for c in centre)})): round-off then limits the accuracy of the results; "
                f"move it near the origin")

    def slenderness_warning(self) -> str:
        """A one-line warning when a beam's cross-section is wider than its shortest segment, else "".

        Rods are slender by assumption; a section as wide as the segments
        between joints usually means the design and the section are in
        different units (the bundled data is in mm), and the equilibria are
        then meaningless (a 10 × 7 section on a design drawn in metres
        collapses its edges in the rest-length solve).
        """
        widths = {}
        for m in self.materials:
            if id(m) not in widths:
                ext = np.asarray(m.fibre_extents)
                widths[id(m)] = float((ext[:, 1] - ext[:, 0]).max())
        size = np.broadcast_to([widths[id(m)] for m in self.materials], (self.num_segments,))
        ratio = size / self._p
        s = int(np.argmax(ratio))
        if ratio[s] <= 1.0:
            return ""
        return (f"the cross-section ({size[s]:.4g} across) is {ratio[s]:.3g}x as wide as {_segment_at(self.design, s)} "
                f"({self._p[s]:.4g} long): "
                f"beams must be slender; are the design and the section in the same units (the bundled data: mm)?")

    def summary(self) -> dict:
        return {"segments": self.num_segments, "joints": self.num_joints, "dof": self.num_vars, "subdivision": self.subdivision}


FAR_FROM_ORIGIN = 1e4
"""Spans from the origin beyond which :meth:`Linkage.offset_warning` speaks (measured: 5.4e4 spans harmless,
5.4e5 spans 0.06 % off in the torque)."""


def _segment_at(design: Design, s: int) -> str:
    """Segment ``s`` as the design file shows it ("the segment on line 29 of d.obj"), not its 0-based index."""
    where = design.where_edge(s)
    of = f" of {design.label()}" if design.source is not None else ""
    return f"the segment on {where}{of}" if where.startswith("line ") else f"{where}{of}"


def _rotate(w: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``exp([ω]×) v`` row by row (Rodrigues; series near ``ω = 0``), NumPy twin of :func:`.joints.rotate`."""
    w, v = w.T, v.T  # component rows (vec): np.cross's copies cost more than the arithmetic at this size
    th2 = vec.dot(w, w)
    small = th2 < 1e-8
    safe = np.where(small, 1.0, th2)
    th = np.sqrt(safe)
    a = np.where(small, 1.0 - th2 / 6.0 + th2 * th2 / 120.0, np.sin(th) / th)
    b = np.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - np.cos(th)) / safe)
    wv = np.array(vec.cross(w, v))
    return (v + a * wv + b * np.array(vec.cross(w, wv))).T


def _update_rod_source_frame(rods: ElasticRods) -> None:
    """:meth:`ElasticRods.update_source_frame` in NumPy (the rods' version calls the JAX reference twist).

    Component rows (:mod:`..rod.vec`) rather than ``(N, 3)`` rows: the same operations in the same order
    (the same numbers to the last bit) without ``np.cross``'s and ``np.stack``'s copies, 0.51 → 0.35 ms
    on the manta ray, once per Newton iteration.
    """
    e = (rods.points[rods.edges[:, 1]] - rods.points[rods.edges[:, 0]]).T
    t = e / np.sqrt(vec.dot(e, e))
    d1 = np.array(vec.parallel_transport(rods.t_src.T, t, rods.d1_src.T))
    if rods.num_stencils:
        e0, e1 = rods.stencil_edges[:, 0], rods.stencil_edges[:, 1]
        t1, r1 = t[:, e1], d1[:, e1]
        u = vec.parallel_transport(t[:, e0], t1, d1[:, e0])
        raw = np.arctan2(vec.dot(vec.cross(u, r1), t1), vec.dot(u, r1))
        rods.ref_twist_src = raw + 2.0 * np.pi * np.round((rods.ref_twist_src - raw) / (2.0 * np.pi))
    d1 = d1 - vec.dot(d1, t) * t
    d1 = d1 / np.sqrt(vec.dot(d1, d1))
    rods.t_src, rods.d1_src = np.ascontiguousarray(t.T), np.ascontiguousarray(d1.T)


class _ReducedHessianAssembler:
    """Assemble ``Jᵀ H_rods J + Σ ∇²(g·joint_map)`` straight into the reduced variables.

    ``J`` is the identity on the rods' free variables; only the variables of
    the joint-controlled terminal edges map nonlinearly (7 outputs of 9 joint
    variables per instance). Every rod stencil (vertex: 11 variables, edge: 6)
    is classified once by which of its variables are controlled and by which
    instance. Its free-free entries go to the reduced pattern as they are,
    whether or not it has controlled variables; for a stencil with ``c``
    controlled variables (rows ``J_c``, ``c × 9`` per joint involved) only
    ``G = B[:, c] J_c`` and ``J_cᵀ G[c]`` are formed, its free-joint and
    joint-joint entries: about a tenth of the arithmetic of ``Pᵀ B P`` with
    the whole local Jacobian ``P``. The pattern and, for each source array
    (vertex blocks, edge blocks, the buffer of those products and the joint
    blocks), a sparse 0/1 matrix that sums its entries into the CSR data are
    built once; a call is a few batched products and three sparse
    matrix-vector products.
    """

    def __init__(self, L: "Linkage"):
        rods = L.rods
        nv = rods.num_vars
        n_inst = L._inst_rows.shape[1]
        rod2red = np.full(nv, -1, np.int64)
        rod2red[L._free_rod] = L._free_reduced
        ctrl_inst = np.full(nv, -1, np.int64)
        ctrl_out = np.full(nv, -1, np.int64)
        ctrl_inst[L._inst_rows] = np.broadcast_to(np.arange(n_inst)[None, :], L._inst_rows.shape)
        ctrl_out[L._inst_rows] = np.broadcast_to(np.arange(7)[:, None], L._inst_rows.shape)
        inst_joint = L._inst_joint
        size = L.num_vars
        self.shape = (size, size)
        # every contribution: (source 0 = vertex blocks, 1 = edge blocks, 2 = product buffer), flat position, row, col
        entries = {0: [], 1: [], 2: []}
        # per group with controlled variables: (source, flat indices of B[:k, c] (n, k, nc) with the free locals'
        # rows first, flat indices of J_c (n, nc, 9 ns) into the instances' Jacobian (its last entry a zero),
        # number of free locals, offset of G (n, k, 9 ns) and of J_cᵀ G[c] (n, 9 ns, 9 ns) in the buffer)
        self.groups = []
        toff = 0
        src_shape = {"v": (13, 13, rods.num_stencils), "e": (7, 7, rods.num_edges)}
        jac_zero = 7 * 9 * n_inst  # index of the zero appended to the flattened (7, 9, N) Jacobian
        for kind, idx_all in (("v", rods.vertex_index[:11]), ("e", rods.edge_index[:6])):
            k, N = idx_all.shape
            if N == 0:
                continue
            src = 0 if kind == "v" else 1
            K0, _, Ns = src_shape[kind]
            inst = ctrl_inst[idx_all]
            first = np.where(inst >= 0, inst, np.iinfo(np.int64).max).min(axis=0)
            second = inst.max(axis=0)
            slot = np.where(inst < 0, -1, np.where(inst == first[None, :], 0, 1))
            code = np.where(inst < 0, -1, slot * 7 + ctrl_out[idx_all])
            sigs, which = np.unique(code.T, axis=0, return_inverse=True)
            which = np.asarray(which).ravel()
            for gi, sig in enumerate(sigs):
                ids = np.flatnonzero(which == gi)
                n = len(ids)
                free_l = np.flatnonzero(sig < 0)
                ctrl_l = np.flatnonzero(sig >= 0)
                red_f = rod2red[idx_all[free_l][:, ids]]  # (nf, n)
                # free-free entries, from the blocks as they are
                aa, bb = np.meshgrid(free_l, free_l, indexing="ij")
                pos = (aa[:, :, None] * K0 + bb[:, :, None]) * Ns + ids[None, None, :]
                entries[src].append((pos.ravel(), np.broadcast_to(red_f[:, None, :], pos.shape).ravel(),
                                     np.broadcast_to(red_f[None, :, :], pos.shape).ravel()))
                if not len(ctrl_l):
                    continue
                nf, nc = len(free_l), len(ctrl_l)
                nslots = 1 + int(max(sig[ctrl_l])) // 7
                slot_inst = [first[ids]] + ([second[ids]] if nslots == 2 else [])
                ns9 = 9 * nslots
                rows_l = np.concatenate([free_l, ctrl_l])  # G's rows: the free locals first
                b_idx = ((rows_l[None, :, None] * K0 + ctrl_l[None, None, :]) * Ns + ids[:, None, None])  # (n, k, nc)
                j_idx = np.full((n, nc, ns9), jac_zero, np.int64)
                for i, l in enumerate(ctrl_l):
                    t, o = int(sig[l]) // 7, int(sig[l]) % 7
                    j_idx[:, i, 9 * t : 9 * t + 9] = (o * 9 + np.arange(9))[None, :] * n_inst + slot_inst[t][:, None]
                jv = np.concatenate([(9 * inst_joint[si])[None, :] + np.arange(9)[:, None] for si in slot_inst])  # (9 ns, n)
                g_off, cc_off = toff, toff + n * k * ns9
                # free-joint entries from G's free rows, both ways round
                pos = g_off + np.arange(n * k * ns9).reshape(n, k, ns9)[:, :nf, :]
                rf = np.broadcast_to(red_f.T[:, :, None], pos.shape)
                cj = np.broadcast_to(jv.T[:, None, :], pos.shape)
                entries[2].append((pos.ravel(), rf.ravel(), cj.ravel()))
                entries[2].append((pos.ravel(), cj.ravel(), rf.ravel()))
                # joint-joint entries
                pos = cc_off + np.arange(n * ns9 * ns9).reshape(n, ns9, ns9)
                entries[2].append((pos.ravel(), np.broadcast_to(jv.T[:, :, None], pos.shape).ravel(),
                                   np.broadcast_to(jv.T[:, None, :], pos.shape).ravel()))
                self.groups.append((src, b_idx, j_idx, nf, g_off, cc_off))
                toff = cc_off + n * ns9 * ns9
        red = (9 * inst_joint)[None, :] + np.arange(9)[:, None]  # (9, n_inst)
        pos = toff + np.arange(n_inst * 81).reshape(n_inst, 9, 9)
        entries[2].append((pos.ravel(), np.broadcast_to(red.T[:, :, None], pos.shape).ravel(),
                           np.broadcast_to(red.T[:, None, :], pos.shape).ravel()))
        self.joint_offset = toff
        self.buffer = np.zeros(toff + 81 * n_inst)
        self._jac_flat = np.zeros(jac_zero + 1)
        all_r = np.concatenate([e[1] for es in entries.values() for e in es])
        all_c = np.concatenate([e[2] for es in entries.values() for e in es])
        # the pattern by SciPy's COO -> CSR conversion (a counting sort by row: 33 ms for a sort of every key)
        P = sp.csr_matrix((np.ones(len(all_r), dtype=np.int32), (all_r, all_c)), shape=(size, size))
        P.sum_duplicates()
        keys = np.repeat(np.arange(size, dtype=np.int64), np.diff(P.indptr)) * size + P.indices
        self.indices = P.indices.astype(np.int32)
        self.indptr = P.indptr.astype(np.int32)
        self.nnz = len(keys)
        sizes = {0: 169 * rods.num_stencils, 1: 49 * rods.num_edges, 2: len(self.buffer)}
        self.gather = {}
        for src, es in entries.items():
            if not es:
                continue
            posv = np.concatenate([e[0] for e in es])
            slots = np.searchsorted(keys, np.concatenate([e[1] for e in es]) * size + np.concatenate([e[2] for e in es]))
            self.gather[src] = sp.csr_matrix((np.ones(len(posv)), (slots, posv)), shape=(self.nnz, sizes[src]))
        # the lower triangle: the gathers' rows of its entries, unchanged (each entry sums the same terms in the same order)
        row_of = keys // size
        self.lower_slots = np.flatnonzero(row_of >= self.indices)
        self.lower_indices = self.indices[self.lower_slots]
        self.lower_indptr = np.searchsorted(row_of[self.lower_slots], np.arange(size + 1)).astype(np.int32)
        self.gather_lower = {src: G[self.lower_slots] for src, G in self.gather.items()}

    def assemble(self, hv, he, jac, hj, lower: bool = False) -> sp.csr_matrix:
        """The reduced Hessian, or with ``lower`` its lower triangle (row ≥ column), the same values."""
        buf = self.buffer
        jflat = self._jac_flat
        jflat[:-1] = jac.ravel()
        flat = (hv.ravel(), he.ravel())
        for src, b_idx, j_idx, nf, g_off, cc_off in self.groups:
            Jc = jflat.take(j_idx)  # (n, nc, 9 ns)
            n, k, _ = b_idx.shape
            ns9 = Jc.shape[2]
            G = buf[g_off : g_off + n * k * ns9].reshape(n, k, ns9)
            np.matmul(flat[src].take(b_idx), Jc, out=G)
            np.matmul(Jc.transpose(0, 2, 1), G[:, nf:], out=buf[cc_off : cc_off + n * ns9 * ns9].reshape(n, ns9, ns9))
        buf[self.joint_offset :].reshape(-1, 9, 9)[:] = hj.transpose(2, 0, 1)
        gather = self.gather_lower if lower else self.gather
        data = gather[2] @ buf
        if 0 in gather:
            data += gather[0] @ flat[0]
        if 1 in gather:
            data += gather[1] @ flat[1]
        return self._matrix(data, lower)

    def lower_of(self, H: sp.csr_matrix) -> sp.csr_matrix:
        """The lower triangle of a matrix that :meth:`assemble` returned whole."""
        return self._matrix(H.data[self.lower_slots], True)

    def _matrix(self, data, lower: bool) -> sp.csr_matrix:
        indices, indptr = (self.lower_indices, self.lower_indptr) if lower else (self.indices, self.indptr)
        H = sp.csr_matrix((data, indices, indptr), shape=self.shape)
        # the constructor may copy the index arrays: share the pattern's own, so that all
        # Hessians of this linkage are recognisably on one pattern (cheap differences)
        H.indices, H.indptr = indices, indptr
        H.has_canonical_format = True
        return H
