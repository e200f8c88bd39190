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

from ..errors import InputError
from ..io.design import Design
from ..rod import ElasticRods
from ..rod import frames
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
            raise InputError(f"rest lengths: segment {bad[0]} has non-positive or non-finite rest length {p[bad[0]]}")

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
            raise InputError(f"segment {bad}: rest length too short for its joint edges at subdivision {k}")

        # ---- joints: initial variables and source frames
        t = g.joint_tangents
        alpha = np.arccos(np.clip(np.sum(t[:, 0] * t[:, 1], axis=1), -1.0, 1.0))
        bad = np.flatnonzero((alpha < 1e-6) | (alpha > np.pi - 1e-6))
        if len(bad):
            jv = int(g.joint_vertex[bad[0]])
            raise InputError(f"joint at vertex {jv}{design.where_vertex(jv) if hasattr(design, 'where_vertex') else ''}: its two beams are parallel (opening angle {np.degrees(alpha[bad[0]]):.3g}°)")
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
            raise InputError(f"reduced variable {int(np.flatnonzero(~np.isfinite(x))[0])} is not finite")
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
            raise InputError(f"rest lengths: segment {s} would get a non-positive edge rest length")
        self.rods.set_rest_lengths(edge)
        self._p = p.copy()

    def update_source_frame(self) -> None:
        """Fold the joint rotations into the source frames (ω ← 0) and update the rods' frames."""
        xj = self._x[: self.num_joint_vars].reshape(-1, 9)
        w = tuple(xj[:, 3:6].T)
        self.joint_b0 = np.stack(jmap.rotate(w, tuple(self.joint_b0.T)), 1)
        self.joint_n0 = np.stack(jmap.rotate(w, tuple(self.joint_n0.T)), 1)
        # re-orthonormalize against drift
        self.joint_b0 /= np.linalg.norm(self.joint_b0, axis=1)[:, None]
        self.joint_n0 -= np.sum(self.joint_n0 * self.joint_b0, 1)[:, None] * self.joint_b0
        self.joint_n0 /= np.linalg.norm(self.joint_n0, axis=1)[:, None]
        theta = self.rods.thetas[self._inst_edge].copy()
        xj[:, 3:6] = 0.0
        self.rods.update_source_frame()
        self._refresh_instance_sources(theta_prev=theta)

    # ---------------------------------------------------------------- energy
    def energy_parts(self):
        return self.rods.energy_parts()

    def energy(self) -> float:
        return self.rods.energy()

    def _instance_jacobian(self):
        """Joint-map outputs (7, N) and Jacobian (7, 9, N) of every instance at the current state."""
        return jk.outputs_and_jacobian(self._instance_q(self._x), self._inst_prm)

    def _jacobian(self):
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
        g = self.rods.gradient(with_rest_lengths)
        nv = self.rods.num_vars
        gx = np.zeros(self.num_vars)
        gx[self._free_reduced] = g[self._free_rod]
        _, jac = self._instance_jacobian()
        contrib = np.einsum("oin,on->in", jac, g[self._inst_rows])
        gx[: self.num_joint_vars] += np.bincount(
            ((9 * self._inst_joint)[None, :] + np.arange(9)[:, None]).ravel(), weights=contrib.ravel(), minlength=self.num_joint_vars
        )
        if not with_rest_lengths:
            return gx
        return np.concatenate([gx, self.rest_length_map.T @ g[nv:]])

    def hessian(self, with_rest_lengths: bool = False) -> sp.csr_matrix:
        """Sparse symmetric Hessian in ``x`` (and ``p`` appended, if asked)."""
        H = self.rods.hessian(with_rest_lengths)
        g = self.rods.gradient()
        J = self._jacobian()
        if with_rest_lengths:
            J = sp.block_diag([J, self.rest_length_map], format="csr")
        Hx = J.T.tocsr() @ (H @ J)
        w = g[self._inst_rows]
        Hj = jk.weighted_hessian(self._instance_q(self._x), self._inst_prm, w)
        n_inst = Hj.shape[2]
        base = (9 * self._inst_joint)[None, None, :]
        rows = np.broadcast_to(base + np.arange(9)[:, None, None], (9, 9, n_inst)).ravel()
        cols = np.broadcast_to(base + np.arange(9)[None, :, None], (9, 9, n_inst)).ravel()
        size = Hx.shape[0]
        return (Hx + sp.csr_matrix((Hj.ravel(), (rows, cols)), shape=(size, size))).tocsr()

    def mass_matrix(self) -> sp.csr_matrix:
        """``Jᵀ M J`` with ``M`` the rods' lumped mass: symmetric positive definite, not lumped."""
        J = self._jacobian()
        return (J.T @ self.rods.mass_matrix() @ J).tocsr()

    def gravity_force(self, g=(0.0, 0.0, -9810.0)) -> np.ndarray:
        """Generalized gravity force on ``x`` (``Jᵀ f`` of the rods' lumped gravity), (num_vars,).

        ``g`` in the input's units (mm/s² for the bundled designs; then
        densities in t/mm³ give forces in N).
        """
        return self._jacobian().T @ self.rods.gravity_force(g)

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

    def summary(self) -> dict:
        return {"segments": self.num_segments, "joints": self.num_joints, "dof": self.num_vars, "subdivision": self.subdivision}
