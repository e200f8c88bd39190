"""Independent checks of a cut list against the design graph and the rest lengths (used by the fabrication tests).

They read only ``cutlist.csv`` and the design's own arrays (vertices, edges,
valences), not the code that wrote the cut list.
"""
import csv
from collections import Counter, defaultdict

import numpy as np


def read_cutlist(path):
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        r["positions"] = [float(x) for x in r["hole_positions_mm"].split()]
        r["joint_ids"] = [int(x) for x in r["joints"].split()]
        r["length"] = float(r["length_mm"])
    return rows


def check_cutlist(path, edges, rest_lengths, to_mm=1.0, margin=None, tol=0.01):
    """Assert every property the fabrication issue lists; return the rows."""
    rows = read_cutlist(path)
    E = np.asarray(edges)
    p = np.asarray(rest_lengths, float) * to_mm
    valence = np.bincount(E.ravel())
    joints = set(np.flatnonzero(valence >= 2).tolist())
    between = defaultdict(list)
    for s, (a, b) in enumerate(E.tolist()):
        between[frozenset((a, b))].append(s)
    with open(path) as fh:
        assert fh.readline().strip() == "beam,family,length_mm,holes,hole_positions_mm,joints,section"
    on_beams = Counter()
    used = Counter()
    for r in rows:
        assert r["family"] in ("A", "B") and r["beam"].startswith(r["family"])
        assert int(r["holes"]) == len(r["positions"]) == len(r["joint_ids"]) >= 1
        assert set(r["joint_ids"]) <= joints
        for j in set(r["joint_ids"]):
            on_beams[j] += 1
        pos = np.array(r["positions"])
        assert np.all(np.diff(pos) > 0)
        assert 0 < pos[0] and pos[-1] < r["length"]
        for (a, b), gap in zip(zip(r["joint_ids"], r["joint_ids"][1:]), np.diff(pos)):
            segs = between[frozenset((a, b))]
            assert segs, f"{r['beam']}: holes {a} and {b} are not joined by a segment"
            s = min(segs, key=lambda k: abs(p[k] - gap))
            assert abs(p[s] - gap) <= tol, (r["beam"], a, b, p[s], gap)
            used[s] += 1
        if margin is not None:
            # beyond the outermost hole: the margin, plus the free-end segment where the beam ends free
            for end_gap, j in ((pos[0], r["joint_ids"][0]), (r["length"] - pos[-1], r["joint_ids"][-1])):
                free = [s for s in range(len(E)) if j in E[s] and min(valence[E[s]]) == 1]
                options = [margin] + [margin + p[s] for s in free]
                assert min(abs(end_gap - o) for o in options) <= tol, (r["beam"], j, end_gap, options)
    assert all(on_beams[j] == 2 for j in joints), [j for j in joints if on_beams[j] != 2][:5]
    joint_to_joint = [s for s in range(len(E)) if valence[E[s, 0]] >= 2 and valence[E[s, 1]] >= 2]
    assert all(used[s] == 1 for s in joint_to_joint)  # each joint-to-joint segment lies between two holes once
    return rows
