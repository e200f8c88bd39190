"""Clearance between the beams of one family in the flat state.

The two families of an X-shell lie in two layers and cross at the joints,
so only beams of the *same* family can collide: in the flat, nearly closed
layout neighbouring beams of a family run side by side, a few beam widths
apart. Where two of them come closer than the beams are wide, the layout
cannot be built.
"""
from __future__ import annotations

import numpy as np


def beam_family(graph, b: int) -> int:
    """The family (0 = A, 1 = B) of beam ``b``: the label most of its segments carry (0 where none is labelled)."""
    labels = graph.segment_labels[np.asarray(graph.beams[b])[:, 0]]
    labels = labels[labels >= 0]
    return int(np.bincount(labels, minlength=2).argmax()) if labels.size else 0


def same_family_pairs(linkage, within: float):
    """Pairs (m, 2) of rod points on two different beams of one family within ``within`` in the plane, with
    the points' positions (n, 2), segments (n,) and beams (n,)."""
    from scipy.spatial import cKDTree

    g = linkage.graph
    rods = linkage.rods
    pts = np.asarray(rods.points)[:, :2]
    seg_of_point = np.repeat(np.arange(rods.num_rods), np.diff(rods.vertex_offsets))  # one rod per segment
    owner = np.asarray(g.beam_of_segment)[seg_of_point]
    family = np.array([beam_family(g, b) for b in range(g.num_beams)])[owner]
    pairs = cKDTree(pts).query_pairs(within, output_type="ndarray").reshape(-1, 2)
    if len(pairs):
        i, j = pairs[:, 0], pairs[:, 1]
        pairs = pairs[(owner[i] != owner[j]) & (family[i] == family[j])]
    return pairs, pts, seg_of_point, owner


def family_clearance(linkage, within: float) -> tuple[float, int, int]:
    """The smallest in-plane distance between rod points of two different beams of one family.

    Only pairs closer than ``within`` are looked at (a k-d tree query).

    Returns
    -------
    (gap, beam_a, beam_b) : (float, int, int)
        ``(inf, -1, -1)`` when no two such points are within ``within``.
    """
    pairs, pts, _, owner = same_family_pairs(linkage, within)
    if not len(pairs):
        return float("inf"), -1, -1
    d = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
    k = int(np.argmin(d))
    return float(d[k]), int(owner[pairs[k, 0]]), int(owner[pairs[k, 1]])


def crowded_segments(linkage, width: float) -> np.ndarray:
    """The segments (sorted) with a rod point closer than ``width`` to a point of another beam of their family."""
    pairs, pts, seg, _ = same_family_pairs(linkage, width)
    if len(pairs):
        pairs = pairs[np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1) < width]
    return np.unique(seg[pairs.ravel()])


def beam_overlaps(linkage, width: float) -> str:
    """Where two beams of the same family come closer than ``width`` ("" if nowhere), in words."""
    gap, a, b = family_clearance(linkage, width)
    if gap >= width:
        return ""
    return f"beams {min(a, b)} and {max(a, b)} come within {gap:.3g} of each other"
