"""Bad input to the rod gets a ValueError naming the vertex or edge."""
import numpy as np
import pytest

from xshells.errors import InputError
from xshells.rod import ElasticRod, ElasticRods

PTS = np.array([[0, 0, 0], [1, 0, 0], [2, 0.5, 0], [3, 0.5, 0.5]], float)
GOOD = dict(stretching=1.0, bending=(1.0, 2.0), twisting=1.0)


def test_input_error_is_a_value_error():
    assert issubclass(InputError, ValueError)


def test_non_finite_coordinates():
    pts = PTS.copy()
    pts[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"vertex 2 of rod 0 is not finite"):
        ElasticRod(pts, **GOOD)


def test_zero_length_edge():
    pts = PTS.copy()
    pts[2] = pts[1]
    with pytest.raises(ValueError, match=r"edge 1 of rod 0 has zero length"):
        ElasticRod(pts, **GOOD)


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("stretching", 0.0, "stretching stiffness must be positive"),
        ("bending", (1.0, -2.0), "bending stiffness must be positive"),
        ("twisting", [1.0, np.inf, 1.0], "twisting stiffness must be positive and finite: edge 1"),
        ("rest_lengths", [1.0, 0.0, 1.0], "rest length must be positive and finite: edge 1"),
        ("density", -1.0, "density must be positive"),
    ],
)
def test_non_positive_parameters(key, value, message):
    kwargs = dict(GOOD)
    kwargs[key] = value
    with pytest.raises(ValueError, match=message):
        ElasticRod(PTS, **kwargs)


def test_mismatched_sizes():
    with pytest.raises(ValueError, match=r"stretching stiffness: expected a scalar or an array of shape \(3,\)"):
        ElasticRod(PTS, **dict(GOOD, stretching=[1.0, 2.0]))
    with pytest.raises(ValueError, match=r"thetas: expected shape \(3,\)"):
        ElasticRod(PTS, **GOOD, thetas=np.zeros(4))
    with pytest.raises(ValueError, match=r"points must have shape"):
        ElasticRod(PTS[:, :2], **GOOD)
    rod = ElasticRod(PTS, **GOOD)
    with pytest.raises(ValueError, match=r"expected 15 variables"):
        rod.set_vars(np.zeros(3))
    with pytest.raises(ValueError, match=r"directors: expected 2 vectors"):
        ElasticRods([PTS, PTS], **GOOD, directors=[[0, 0, 1]])


def test_unknown_bending_variant():
    with pytest.raises(ValueError, match="bending_energy"):
        ElasticRod(PTS, **GOOD, bending_energy="2020")
