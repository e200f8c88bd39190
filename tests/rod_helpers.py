"""Shared constructions for the rod tests."""
import numpy as np

from xshells.rod import ElasticRod


def random_rod(seed=0, n=10, variant="2008", curved_rest=False):
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n + 1)
    pts = np.stack([s, 0.2 * np.sin(3 * s), 0.1 * s**2], axis=1) + 0.02 * rng.standard_normal((n + 1, 3))
    kwargs = dict(
        stretching=50.0 + 10 * rng.random(n),
        bending=np.stack([1.0 + rng.random(n), 2.0 + rng.random(n)], axis=1),
        twisting=0.5 + rng.random(n),
        thetas=0.3 * rng.standard_normal(n),
        rest_lengths=(1.0 / n) * (1 + 0.1 * rng.random(n)),
        bending_energy=variant,
        density=1.0 + rng.random(n),
        area=0.01,
    )
    if curved_rest:
        kwargs["rest_shape"] = pts + 0.05 * rng.standard_normal(pts.shape)
        kwargs["rest_thetas"] = 0.2 * rng.standard_normal(n)
    rod = ElasticRod(pts, **kwargs)
    # move away from the construction state, then make it the source frame
    x = rod.get_vars()
    rod.set_vars(x + 0.03 * rng.standard_normal(len(x)))
    rod.update_source_frame()
    return rod


def straight_rod(n, length=1.0, EI=1.0, GJ=1.0, EA=1e7, **kw):
    pts = np.zeros((n + 1, 3))
    pts[:, 0] = np.linspace(0.0, length, n + 1)
    return ElasticRod(pts, stretching=EA, bending=(EI, EI), twisting=GJ, **kw)


def coord(v, c):
    """Index of coordinate c of vertex v."""
    return 3 * v + c
