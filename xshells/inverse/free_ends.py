"""Free ends: each beam continued from its last joint to the surface's boundary.

Why. A net's beams end at their last joint inside the surface, up to a
spacing short of the boundary, so a band along the boundary lies farther
than 0.75 spacings from any beam and the coverage falls short (the pointy
wings: 89.6 %). A designer lets the beams run on to the edge as free ends.

Each beam end is continued straight in the scissor map's closed chart
(:mod:`.scissor`; the beams are nearly straight there) until it leaves the
chart or reaches ``MAX_LENGTH`` spacings; the free end is put where it
leaves, on the surface. Its flat position continues the beam's last flat
segment by the same length, so the flat beam stays smooth.

In the lattice of the net's beams, a continuation shorter than a spacing
never reaches the next beam of the other family (that one is a spacing
along), so on an even net free ends cross no beam where no joint is; where
a flat layout bends them across one all the same (a fan, a curved flat
beam), they are left off (:func:`crossing_ends`).

The free ends are attached to each stage's flat layout (:func:`attach`), not
optimized with it; one that comes closer to a neighbouring beam of its family
than a beam's width, or crosses another beam without a joint, is left off (:mod:`.run`). They carry no load, so they barely change the deployment
(28 added to the wings' design moved its joints by 3.5e-5 of the span); but
optimized with them, the wings reached 0.66 % / 2.80 % instead of 0.50 % /
1.46 %: the joints where both beams end (weighted 10× in the fit) are no
longer corners, and the optimization takes another path. A segment to a free
end keeps its rest length in the rest-length solve and in the design
optimization of a net that has them (a designer's ``--net``): nothing else
fixes it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .net import Net
from .scissor import ScissorMap
from .surface import TargetSurface

#: the longest free end, in spacings: below one, it stops short of the other family's next beam
MAX_LENGTH = 0.9
#: the shortest free end kept, in spacings: a shorter one covers little and is only an offcut
MIN_LENGTH = 0.25
#: samples along a continuation when looking for where it leaves the surface
SAMPLES = 36
#: bisections of the sample interval where a continuation leaves the surface (2⁻²⁰ of it)
BISECTIONS = 20
#: rescalings of a continuation whose length on the surface exceeds the cap (the chart is smooth along it)
CAP_ITERATIONS = 4


def beam_ends(net: Net) -> np.ndarray:
    """The beam ends of a net: rows ``(joint, previous joint, family)``, shape (e, 3).

    A joint is a beam's end in a family when exactly one segment of that
    family meets it; the previous joint is that segment's other end.
    """
    rows = []
    for f in (0, 1):
        segs = net.segments[net.family == f]
        count = np.bincount(segs.ravel(), minlength=net.num_joints)
        for a, b in segs:
            if count[a] == 1:
                rows.append((a, b, f))
            if count[b] == 1:
                rows.append((b, a, f))
    return np.asarray(rows, np.int64).reshape(-1, 3)


@dataclass(frozen=True)
class FreeEnds:
    """The continuations of a net's beam ends (e of them): the free ends to attach.

    Attributes
    ----------
    joint, previous, family : (e,) int64
        The beam end: its joint, the joint before it on the beam, the beam's family.
    length : (e,) float
        How far the beam runs on, on the surface (the free end's segment length).
    point : (e, 3) float
        Where the free end lies on the surface.
    outward : (e,) bool
        Whether the beam's segments run towards the end (the new segment then runs joint → free end).
    """

    joint: np.ndarray
    previous: np.ndarray
    family: np.ndarray
    length: np.ndarray
    point: np.ndarray
    outward: np.ndarray

    def __len__(self) -> int:
        return len(self.joint)

    def subset(self, keep: np.ndarray) -> "FreeEnds":
        """These free ends where ``keep`` (e,) is True."""
        keep = np.asarray(keep, bool)
        return FreeEnds(self.joint[keep], self.previous[keep], self.family[keep], self.length[keep],
                        self.point[keep], self.outward[keep])


def continuations(net: Net, surface: TargetSurface, smap: ScissorMap, spacing: float,
                  max_length: float = MAX_LENGTH, min_length: float = MIN_LENGTH) -> FreeEnds:
    """Each beam end continued to the surface's boundary (see the module); those shorter than ``min_length``
    spacings are left out, none is longer than ``max_length`` spacings.

    Parameters
    ----------
    net : Net
        Joints on the surface (k, 3), segments and families.
    surface, smap :
        The target and its scissor map (whose closed chart the continuations follow).
    spacing : float
        The net's joint spacing.
    """
    from .fanned import ChartLift
    from .flatten import chart

    ends = beam_ends(net)
    if len(ends) == 0:
        return _none()
    lift = ChartLift(surface, smap)
    inside_tol = 1e-9 * float(np.ptp(smap.flat, axis=0).max())
    U, _ = chart(surface, smap)(net.joints)
    j, o, fam = ends.T
    d = U[j] - U[o]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    t = max_length * spacing * np.arange(1, SAMPLES + 1) / SAMPLES  # chart lengths along the continuation
    P = U[j][:, None, :] + t[None, :, None] * d[:, None, :]  # (e, SAMPLES, 2)
    _, out = lift.faces(P.reshape(-1, 2))
    inside = (out <= inside_tol).reshape(len(ends), SAMPLES)
    last = np.cumprod(inside, axis=1).sum(axis=1) - 1  # the last sample before the continuation first leaves
    keep = last >= 0
    # where it leaves: bisection between that sample and the next
    lo = t[last[keep]]
    hi = np.where(last[keep] + 1 < SAMPLES, t[np.minimum(last[keep] + 1, SAMPLES - 1)], lo)
    base, dk = U[j[keep]], d[keep]
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        _, out = lift.faces(base + mid[:, None] * dk)
        ok = out <= inside_tol
        lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
    j, o, fam = j[keep], o[keep], fam[keep]
    # the cap is on the surface: along a beam that is not one of the chart's families, the closed chart
    # shortens lengths (a fanned net's free ends on the barrel vault ran 3.7 spacings for a chart length of 0.9)
    cap = max_length * spacing
    for it in range(CAP_ITERATIONS + 1):
        X_end, _ = lift(base + lo[:, None] * dk)
        length = np.linalg.norm(X_end - net.joints[j], axis=1)
        over = length > cap
        if not over.any() or it == CAP_ITERATIONS:
            break
        lo = np.where(over, lo * cap / np.maximum(length, 1e-300), lo)
    ok = length >= min_length * spacing
    # the segment before the end runs into it (o → j) or out of it
    into = {(int(a), int(b), int(f)) for (a, b), f in zip(net.segments, net.family)}
    outward = np.array([(int(b), int(a), int(f)) in into for a, b, f in zip(j[ok], o[ok], fam[ok])], bool)
    return FreeEnds(j[ok], o[ok], fam[ok], length[ok], X_end[ok], outward)


def _none() -> FreeEnds:
    e = np.zeros(0, np.int64)
    return FreeEnds(e, e, e, np.zeros(0), np.zeros((0, 3)), np.zeros(0, bool))


def attach(points: np.ndarray, segments: np.ndarray, ends: FreeEnds, rest_lengths: np.ndarray | None = None):
    """A layout with the free ends attached: each beam end's last segment continued straight by its length.

    Parameters
    ----------
    points : (k, d) float
        The joints (the net's numbering), flat (d = 2 or 3) or not.
    segments : (s, 2) int
    ends : FreeEnds
    rest_lengths : (s,) float, optional
        Extended by the free ends' lengths when given.

    Returns
    -------
    points (k + e, d), segments (s + e, 2) and, when given, rest_lengths (s + e,): the free ends after the rest.
    """
    points = np.asarray(points, float)
    e = points[ends.joint] - points[ends.previous]
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    new = np.arange(len(points), len(points) + len(ends))
    seg = np.where(ends.outward[:, None], np.c_[ends.joint, new], np.c_[new, ends.joint])
    out = (np.vstack([points, points[ends.joint] + ends.length[:, None] * e]),
           np.vstack([np.asarray(segments, np.int64).reshape(-1, 2), seg]).astype(np.int64))
    if rest_lengths is None:
        return out
    return out + (np.r_[np.asarray(rest_lengths, float), ends.length],)


def add_free_ends(net: Net, surface: TargetSurface, smap: ScissorMap, spacing: float,
                  max_length: float = MAX_LENGTH, min_length: float = MIN_LENGTH) -> Net:
    """The net with its beams continued to the boundary (:func:`continuations`): the free ends after the joints
    on the surface, their flat positions continuing each beam's last flat segment, their segments after the net's."""
    ends = continuations(net, surface, smap, spacing, max_length, min_length)
    if len(ends) == 0:
        return net
    flat, segments = attach(net.flat, net.segments, ends)
    return Net(np.vstack([net.joints, ends.point]), flat, segments, np.r_[net.family, ends.family].astype(np.int64))


def crossing_ends(points: np.ndarray, segments: np.ndarray, first_end: int) -> np.ndarray:
    """Indices (from 0, into the free ends) of the free-end segments that cross another segment without a joint.

    ``points`` (k, ≥2): the flat layout (its first two coordinates are used); ``segments`` (s, 2), of which those
    from ``first_end`` on are the free ends' (as :func:`attach` appends them). The lattice argument of this
    module's docstring holds for an even net, but a fan or a curved flat beam can bend a free end across a
    beam of the other family (recheck 34: omsh's flat design, kept as valid with no word). A proper crossing (each
    segment's ends strictly on both sides of the other's line, beyond round-off) of two segments that share no
    node, found by :func:`xshells.linkage.graph.segment_crossings` as the design reader finds them; of two crossing free ends the
    later one is named, so that leaving it off clears the pair.
    """
    E = np.asarray(segments, np.int64)
    if first_end >= len(E):
        return np.zeros(0, np.int64)
    from ..linkage.graph import segment_crossings

    s, t, cross, _ = segment_crossings(np.asarray(points, float)[:, :2], E)
    cross &= t >= first_end
    return np.unique(t[cross]) - first_end
