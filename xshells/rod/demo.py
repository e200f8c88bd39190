"""A small end-to-end rod demo: the pinned–pinned elastica against its closed form.

Used by ``xshells demo`` until the linkage deployment lands. Writes
``elastica.png`` (shapes at 10 and 40 edges over the exact curve) and
``elastica.json`` (end force and midpoint height against the exact values).
"""
from __future__ import annotations

import json
import os
import time

import numpy as np
from scipy.optimize import brentq
from scipy.special import ellipe, ellipeinc, ellipk, ellipkinc

from ..solve import NewtonOptions, minimize
from .rods import ElasticRod


def exact_elastica(a: float, L: float = 1.0, EI: float = 1.0, samples: int = 200):
    """Closed-form pinned–pinned elastica with ends ``a·L`` apart.

    Returns
    -------
    shape : (samples, 2) array, force : float, height : float
    """
    m = brentq(lambda m: 2 * ellipe(m) / ellipk(m) - 1 - a, 1e-12, 1 - 1e-12)
    C = 1 / (2 * ellipk(m))
    phi = np.linspace(-np.pi / 2, np.pi / 2, samples)
    x = L * C * (2 * ellipeinc(phi, m) - ellipkinc(phi, m))
    y = 2 * L * C * np.sqrt(m) * np.cos(phi)
    return np.stack([x - x[0], y], axis=1), EI / (L * C) ** 2, 2 * L * C * np.sqrt(m)


def solve_elastica(n: int, a: float, L: float = 1.0, EI: float = 1.0):
    """Discrete elastica with ``n`` edges; returns (points (n+1, 3), end force)."""
    s = np.linspace(0.0, L, n + 1)
    R = brentq(lambda R: 2 * R * np.sin(L / (2 * R)) - a * L, L / (2 * np.pi) * 1.0001, 1e3 * L)
    phi = (s - L / 2) / R
    pts = np.zeros((n + 1, 3))
    pts[:, 0] = a * L / 2 + R * np.sin(phi)
    pts[:, 1] = R * (np.cos(phi) - np.cos(L / (2 * R)))
    rod = ElasticRod(pts, stretching=1e6 * EI / L**2, bending=(EI, EI), twisting=EI, rest_lengths=np.full(n, L / n))
    V = rod.num_vertices
    fixed = [0, 1, 2, 3 * n, 3 * n + 1, 3 * n + 2] + [3 * v + 2 for v in range(1, n)] + [3 * V]
    report = minimize(rod, fixed=fixed, options=NewtonOptions(gradient_tolerance=1e-8 * EI / L**2))
    if not report.converged:
        raise RuntimeError(f"elastica with {n} edges did not converge: {report.message}")
    return rod.points.copy(), abs(rod.gradient()[3 * n])


def run(out_dir: str, a: float = 0.6, edges=(10, 40)) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(out_dir, exist_ok=True)
    start = time.perf_counter()
    shape, force, height = exact_elastica(a)
    result = {"a_over_L": a, "exact": {"force": force, "height": height}, "discrete": []}
    fig, ax = plt.subplots(figsize=(6, 3.2))
    ax.plot(shape[:, 0], shape[:, 1], "k-", lw=3, alpha=0.3, label="exact")
    for n in edges:
        pts, f = solve_elastica(n, a)
        h = pts[n // 2, 1]
        result["discrete"].append(
            {"edges": n, "force": f, "height": h, "force_error": abs(f - force) / force, "height_error": abs(h - height) / height}
        )
        ax.plot(pts[:, 0], pts[:, 1], "o-", ms=3, label=f"{n} edges: F error {abs(f - force) / force:.2%}")
    ax.set_aspect("equal")
    ax.set_title(f"Pinned–pinned elastica, a/L = {a}")
    ax.legend(fontsize=8)
    result["time_s"] = time.perf_counter() - start
    _save_figure(fig, os.path.join(out_dir, "elastica.png"))
    plt.close(fig)
    _write_json(os.path.join(out_dir, "elastica.json"), result)
    return result


def _save_figure(fig, path: str) -> None:
    tmp = path + ".tmp.png"
    fig.savefig(tmp, dpi=120, bbox_inches="tight")
    os.replace(tmp, path)


def _write_json(path: str, data) -> None:
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(data, fh, indent=1)
    os.replace(tmp, path)
