"""Clearance between beams of one family in the flat state: hand-computed on rhombic grids."""
import numpy as np
import pytest

from xshells.linkage.clearance import beam_overlaps, crowded_segments, family_clearance
from xshells.linkage.grids import rhombic_grid
from xshells.linkage.linkage import Linkage
from xshells.section import Material

RECT = Material.uniform("rectangle", [10, 7], E=20000, nu=0.3)


@pytest.mark.parametrize("angle_deg", [60.0, 90.0])
def test_neighbouring_straight_beams_are_the_spacing_times_sin_angle_apart(angle_deg):
    """Family-0 beams of a rhombic grid are parallel lines |b| sin α apart. A segment's rod points are
    l/(k-1) apart, the end ones half an edge beyond its joints; with k = 3 (edges of 50) the neighbour's
    points at 60° (50 along) line up with these, so the nearest points are exactly |b| sin α apart."""
    L = Linkage(rhombic_grid(3, 3, spacing=100.0, angle=np.radians(angle_deg)), RECT, subdivision=3)
    gap, a, b = family_clearance(L, 150.0)
    assert gap == pytest.approx(100.0 * np.sin(np.radians(angle_deg)), rel=1e-12)
    assert a != b and a >= 0 and b >= 0


def test_nothing_within_reach_is_infinite_and_overlaps_are_named():
    L = Linkage(rhombic_grid(3, 3, spacing=100.0, angle=np.radians(60.0)), RECT, subdivision=3)
    assert family_clearance(L, 50.0) == (float("inf"), -1, -1)
    assert beam_overlaps(L, 86.0) == ""
    msg = beam_overlaps(L, 87.0)
    assert msg.startswith("beams ") and "come within 86.6 of each other" in msg


def test_the_other_family_and_segments_meeting_at_a_joint_do_not_count():
    """Closed to 20°, the two families nearly coincide near the joints (they cross there); only same-family
    beams, 100 sin 20° = 34.2 apart at least, count."""
    L = Linkage(rhombic_grid(4, 4, spacing=100.0, angle=np.radians(20.0)), RECT, subdivision=6)
    gap, _, _ = family_clearance(L, 100.0)
    assert gap >= 100.0 * np.sin(np.radians(20.0)) - 1e-9


def test_crowded_segments_are_those_of_the_overlap():
    """At 60° every beam of either family has a neighbour 86.6 away along its whole length: at a width of 87
    every segment is crowded, at 86 none is."""
    L = Linkage(rhombic_grid(3, 3, spacing=100.0, angle=np.radians(60.0)), RECT, subdivision=3)
    assert crowded_segments(L, 86.0).size == 0
    assert crowded_segments(L, 87.0).tolist() == list(range(L.num_segments))
