"""Faults found by a re-check of the rod: each bad input gets one ValueError naming the rod, vertex or edge.

Before these fixes the inputs below gave NaN energies, were silently ignored or cast, or failed
with raw NumPy / TypeError / OverflowError messages.
"""
import warnings

import numpy as np
import pytest

from xshells.errors import InputError, InvalidState
from xshells.rod import ElasticRod, ElasticRods

PTS = np.array([[0, 0, 0], [1, 0, 0], [2, 0.5, 0], [3, 0.5, 0.5]], float)
GOOD = dict(stretching=10.0, bending=(1.0, 2.0), twisting=1.0)
STRAIGHT = np.c_[np.linspace(0, 1, 5), np.zeros(5), np.zeros(5)]
CURVED = np.array([[0, 0, 0], [1, 0, 0], [2, 0.3, 0], [3, 0.2, 0.4], [4, 0, 0.5]])


def one_value_error(f, match):
    """``f()`` raises a ValueError (no NumPy warning on the way) whose message matches ``match``."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a ComplexWarning or RuntimeWarning on the way is a fault too
        with pytest.raises(ValueError, match=match) as info:
            f()
    assert "\n" not in str(info.value)
    return info.value


# ---------------------------------------------------------------- 1: reversed edges
@pytest.mark.parametrize(
    "current, rest, edge",
    [
        (-STRAIGHT, STRAIGHT, 0),  # a straight rod built pointing the other way from its straight rest shape
        (CURVED * [-1, -1, 1], CURVED, 0),  # the rest shape turned 180° about z
        (PTS[::-1].copy(), PTS, 1),  # walked backwards: edge 1 is reversed
    ],
)
def test_current_edge_opposite_its_rest_edge_is_refused(current, rest, edge):
    one_value_error(lambda: ElasticRod(current, rest_shape=rest, **GOOD),
                    rf"edge {edge} of rod 0 points \(nearly\) opposite its rest edge")


def test_reversed_edge_names_its_rod_in_a_set():
    one_value_error(lambda: ElasticRods([CURVED, -STRAIGHT], rest_shape=[CURVED, STRAIGHT], **GOOD),
                    r"edge 0 of rod 1 points \(nearly\) opposite")


def test_nearly_reversed_but_well_conditioned_edge_is_accepted():
    # turned 179.9° about z: transport is still well defined, the energy finite
    a = np.radians(179.9)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rod = ElasticRod(CURVED @ R.T, rest_shape=CURVED, **GOOD)
    assert np.isfinite(rod.energy()) and np.isfinite(rod.gradient()).all()


def test_rigidly_turned_rest_shape_is_strained_as_documented():
    # the docstring says so: the current frames are the rest frames carried edge by edge
    a = 1.5
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    assert ElasticRod(CURVED @ R.T, rest_shape=CURVED, **GOOD).energy() > 0.1
    assert "not* an" in ElasticRods.__doc__ and "starts at\n        zero" not in ElasticRods.__doc__


def test_set_vars_reversing_an_edge_is_an_invalid_state():
    rod = ElasticRod(STRAIGHT, **GOOD)
    x = rod.get_vars()
    x[12:15] = [0.5, 0, 0]  # the last edge now points -x, opposite its source frame's tangent
    with pytest.raises(InvalidState, match=r"state: edge 3 of rod 0 points \(nearly\) opposite"):
        rod.set_vars(x)
    assert np.isfinite(rod.energy())  # the state was left as it was
    x[12:15] = [0.5, 0.01, 0]  # turned back by 178.9°: allowed
    rod.set_vars(x)
    assert np.isfinite(rod.energy())


def test_set_vars_folding_the_rod_back_is_an_invalid_state():
    # edge 1 turns by 90° only (no reversal against its source frame), but the rod then folds back at vertex 1
    rod = ElasticRods([PTS, np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.0]])], **GOOD)
    x = rod.get_vars()
    x[18:21] = [0, 0, 0]  # vertex 2 of rod 1 onto vertex 0
    with pytest.raises(InvalidState, match=r"state: the rod folds back at vertex 1 of rod 1"):
        rod.set_vars(x)
    assert np.isfinite(rod.energy())
    x[18:21] = [0, 0.01, 0]  # a sharp but finite turn: allowed
    rod.set_vars(x)
    assert np.isfinite(rod.energy())


def test_rod_folding_back_is_refused():
    folded = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0.0], [0, 1, 0]])
    one_value_error(lambda: ElasticRod(folded, **GOOD), r"folds back at vertex 1 of rod 0")


# ---------------------------------------------------------------- 2: directors
@pytest.mark.parametrize(
    "directors, match",
    [
        ([1, 0, 0], r"director of rod 0 .* is along the rod's first edge"),
        ([0, 0, 0], r"director of rod 0 is zero"),
        ([np.nan, 0, 1], r"director of rod 0 is not finite"),
        ([0, 1], r"directors: expected 1 vector \(one per rod\) of 3 components, got shape \(1, 2\)"),
        ([0, 1j, 1], r"directors: expected real numbers, got complex"),
    ],
)
def test_bad_directors(directors, match):
    one_value_error(lambda: ElasticRod(PTS, directors=directors, **GOOD), match)


def test_bad_director_names_its_rod():
    one_value_error(lambda: ElasticRods([PTS, PTS], directors=[[0, 0, 1], [2, 0, 0]], **GOOD),
                    r"director of rod 1 .* along")


def test_good_director_still_accepted():
    rod = ElasticRod(PTS, directors=[1, 1, 0], **GOOD)  # not along the edge: its normal part is used
    assert np.isfinite(rod.energy())
    assert ElasticRod(PTS, directors=[[1, 1, 0]], **GOOD).energy() == rod.energy()  # one rod's, nested


# ---------------------------------------------------------------- 3: set_vars angles
@pytest.mark.parametrize("value", [np.nan, np.inf])
def test_set_vars_refuses_non_finite_angles(value):
    rod = ElasticRod(PTS, **GOOD)
    x = rod.get_vars()
    x[-1] = value
    with pytest.raises(InvalidState, match=r"state: the material angle of edge 2 of rod 0 is not finite"):
        rod.set_vars(x)


# ---------------------------------------------------------------- 4: rest_thetas
def test_rest_thetas_without_rest_shape_apply_to_the_straight_rest_shape():
    straight = np.c_[np.linspace(0, 3, 4), np.zeros(4), np.zeros(4)]
    a = ElasticRod(straight, rest_thetas=[0, 1.0, 2.0], **GOOD)
    b = ElasticRod(straight, rest_shape=straight, rest_thetas=[0, 1.0, 2.0], **GOOD)
    assert a.energy_parts().twist == pytest.approx(b.energy_parts().twist) == pytest.approx(1.0)
    np.testing.assert_allclose(a.twist_bar, b.twist_bar, atol=1e-12)
    # on a curved rod too: the twist is measured against the rest twist, the curvature against straight
    c = ElasticRod(PTS, rest_thetas=[0.0, 0.5, 0.5], thetas=[0.0, 0.5, 0.5], **GOOD)
    assert c.energy_parts().twist == pytest.approx(ElasticRod(PTS, **GOOD).energy_parts().twist)


# ---------------------------------------------------------------- 5, 6: types and extreme values
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(rods=[PTS + 1j]), r"rod 0 points: expected real numbers, got complex"),
        (dict(rods=[PTS + 0j]), r"rod 0 points: expected real numbers, got complex"),
        (dict(rods=[[[0, 0, 0], [1, 0]]]), r"rod 0 points: expected a rectangular array"),
        (dict(rods=[[["a", "b", "c"], ["d", "e", "f"]]]), r"rod 0 points: expected real numbers, got text"),
        (dict(rods=[PTS, [[0, 0, 0], [1, 0]]]), r"rod 1 points: expected a rectangular array"),
        (dict(stretching=1 + 1j), r"stretching stiffness: expected real numbers, got complex"),
        (dict(stretching="abc"), r"stretching stiffness: expected real numbers, got text"),
        (dict(stretching=None), r"stretching stiffness: expected real numbers, got NoneType"),
        (dict(twisting=10**400), r"twisting stiffness: a value is too large"),
        (dict(bending=(1.0, 2j)), r"bending stiffness: expected real numbers, got complex"),
        (dict(rest_lengths=[1, 1, 1j]), r"rest length: expected real numbers, got complex"),
        (dict(thetas=[0, 1j, 0]), r"thetas: expected real numbers, got complex"),
        (dict(thetas=["0", "1", "2"]), r"thetas: expected real numbers, got text"),
        (dict(rest_shape=[PTS + 1j]), r"rest_shape of rod 0: expected real numbers, got complex"),
        (dict(rest_shape=[PTS], rest_thetas=[0, 1j, 0]), r"rest_thetas: expected real numbers, got complex"),
    ],
)
def test_complex_and_non_numeric_inputs(kwargs, match):
    kw = dict(GOOD, rods=[PTS])
    kw.update(kwargs)
    one_value_error(lambda: ElasticRods(**kw), match)


def test_huge_coordinates_name_the_vertex():
    one_value_error(lambda: ElasticRod(PTS * 1e200, **GOOD), r"vertex 1 of rod 0 has a coordinate beyond 1e\+150")
    rod = ElasticRod(PTS, **GOOD)
    x = rod.get_vars()
    x[6] = 1e300
    with pytest.raises(InvalidState, match=r"state: vertex 2 of rod 0 has a coordinate beyond"):
        rod.set_vars(x)
    assert np.isfinite(ElasticRod(PTS * 1e140, **GOOD).energy())  # large but representable: accepted


def test_set_vars_refuses_complex_state():
    rod = ElasticRod(PTS, **GOOD)
    one_value_error(lambda: rod.set_vars(rod.get_vars() + 1j), r"state: expected real numbers, got complex")


# ---------------------------------------------------------------- 7: messages and unchecked arguments
def test_scalar_thetas_are_broadcast():
    rod = ElasticRod(PTS, thetas=0.3, **GOOD)
    np.testing.assert_array_equal(rod.thetas, [0.3, 0.3, 0.3])
    np.testing.assert_allclose(ElasticRod(PTS, rest_shape=PTS, rest_thetas=0.3, **GOOD).twist_bar, [0.0, 0.0], atol=1e-12)


def test_messages_in_a_set_name_the_rod_and_its_own_edge():
    one_value_error(lambda: ElasticRods([PTS, PTS], **dict(GOOD, stretching=[1, 1, 1, 1, -1, 1])),
                    r"stretching stiffness must be positive and finite: edge 1 of rod 1 has -1.0")
    one_value_error(lambda: ElasticRods([PTS, PTS], **GOOD, thetas=[0, 0, 0, 0, np.nan, 0]),
                    r"thetas: edge 1 of rod 1 is not finite")
    one_value_error(lambda: ElasticRods([PTS, PTS], **GOOD, rest_shape=[PTS, PTS[:3]]),
                    r"rest_shape of rod 1: expected shape \(4, 3\)")
    one_value_error(lambda: ElasticRods([PTS, PTS], **GOOD, rest_shape=[PTS]),
                    r"rest_shape: expected 2 rods")
    rods = ElasticRods([PTS, PTS], **GOOD)
    one_value_error(lambda: rods.set_rest_lengths([1, 1, 1, 1, 0, 1]), r"rest length .* edge 1 of rod 1 has 0.0")


def test_gravity_g_is_checked():
    rod = ElasticRod(PTS, **GOOD)
    one_value_error(lambda: rod.gravity_force((0, -9.81)), r"gravity g: expected a vector of 3 components")
    one_value_error(lambda: rod.gravity_force((0, 0, np.nan)), r"gravity g: not finite")
    one_value_error(lambda: rod.gravity_force((0, 0, -9.81j)), r"gravity g: expected real numbers")
    assert rod.gravity_force((0, 0, -2.0))[2] < 0


@pytest.mark.parametrize("density", [-1.0, 0.0, np.nan, [1.0, -1.0, 1.0]])
def test_mass_density_is_checked(density):
    rod = ElasticRod(PTS, **GOOD)
    one_value_error(lambda: rod.mass_matrix(density=density), r"density must be positive and finite: edge \d of rod 0")
    one_value_error(lambda: rod.vertex_masses(density=density), r"density must be positive and finite")


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(young=1.0, shear=1.0, fibre=(1, 2, 3)), r"fibre: expected a scalar or an array of shape \(3, 2\)"),
        (dict(young=-1.0, shear=1.0, fibre=(1, 2)), r"young must be positive and finite: edge 0 of rod 0"),
        (dict(young=1.0, shear=np.nan, fibre=(1, 2)), r"shear must be positive and finite"),
        (dict(young=1.0 + 1j, shear=1.0, fibre=(1, 2)), r"young: expected real numbers"),
    ],
)
def test_stress_measure_arguments_are_checked(kwargs, match):
    rod = ElasticRod(PTS, **GOOD)
    one_value_error(lambda: rod.stress_measures(**kwargs), match)


# ---------------------------------------------------------------- 8: demo help
def test_demo_help_describes_the_command_and_its_options(capsys):
    from xshells.cli import main

    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "manta-ray" in text and "deployment increments" in text and "no progress bar" in text
