"""Dimensioned drawings of the parametric profiles, for ``docs/sections.md``.

    python -m xshells.section.diagrams docs/img

writes ``section_<type>.png`` for each type: the profile filled, each
parameter drawn as a dimension line, and the profile's x and y axes at
the centroid (x goes along the rod's d1 when these axes are principal).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from .profiles import make_profile
from .properties import centroidal_moments, profile_moments

# (type, example parameters, file stem, dimension lines: (label, start, end, label offset))
DRAWINGS = [
    ("rectangle", [10, 6], "rectangle", [
        ("width", (-5, -3.8), (5, -3.8), (0, -0.7)),
        ("height", (5.8, -3), (5.8, 3), (0.9, 0)),
    ]),
    ("ellipse", [5, 3], "ellipse", [
        ("a", (0, -3.8), (5, -3.8), (0, -0.6)),
        ("b", (-5.8, 0), (-5.8, 3), (-0.6, 0)),
    ]),
    ("I", [3, 2, 3, 1.5, 6, 1.5], "I", [
        ("w1", (0, -0.8), (3, -0.8), (0, -0.6)),
        ("w2", (3, -0.8), (5, -0.8), (0, -0.6)),
        ("w3", (5, -0.8), (8, -0.8), (0, -0.6)),
        ("h1", (8.8, 0), (8.8, 1.5), (0.7, 0)),
        ("h2", (8.8, 1.5), (8.8, 7.5), (0.7, 0)),
        ("h3", (8.8, 7.5), (8.8, 9), (0.7, 0)),
    ]),
    ("L", [8, 6, 1.5, 2], "L", [
        ("a", (0, -0.8), (8, -0.8), (0, -0.6)),
        ("b", (-0.8, 0), (-0.8, 6), (-0.6, 0)),
        ("t1", (8.8, 0), (8.8, 1.5), (0.7, 0)),
        ("t2", (0, 6.8), (2, 6.8), (0, 0.6)),
    ]),
    ("+", [10, 8, 2, 3], "plus", [
        ("a", (-5, -4.8), (5, -4.8), (0, -0.6)),
        ("b", (5.8, -4), (5.8, 4), (0.7, 0)),
        ("t1", (-5.8, -1), (-5.8, 1), (-0.7, 0)),
        ("t2", (-1.5, 4.8), (1.5, 4.8), (0, 0.6)),
    ]),
]


def draw(kind: str, params: list, dimensions: list, path: Path) -> None:
    """Save one dimensioned drawing as a small PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    profile = make_profile(kind, params)
    _, centroid, _ = centroidal_moments(profile_moments(profile))
    fig, ax = plt.subplots(figsize=(3.2, 2.8), dpi=80)
    outline = np.vstack((profile.outer, profile.outer[:1]))
    ax.fill(outline[:, 0], outline[:, 1], color="#d8e2ef", edgecolor="#34495e", linewidth=1.2)
    for label, start, end, offset in dimensions:
        ax.annotate("", xy=end, xytext=start, arrowprops=dict(arrowstyle="<->", color="#c0392b", lw=0.9))
        middle = (np.add(start, end)) / 2 + offset
        ax.text(*middle, label, color="#c0392b", ha="center", va="center", fontsize=9)
    span = np.ptp(profile.outer, axis=0).max()
    for direction, name in (((1, 0), "x"), ((0, 1), "y")):
        tip = centroid + 0.22 * span * np.array(direction)
        ax.annotate("", xy=tip, xytext=centroid, arrowprops=dict(arrowstyle="->", color="#2c3e50", lw=0.8))
        ax.text(*(tip + 0.05 * span * np.array(direction)), name, fontsize=7, color="#2c3e50",
                ha="left" if direction[0] else "center", va="bottom" if direction[1] else "center")
    ax.plot(*centroid, "o", color="#2c3e50", markersize=3)
    # annotations do not count towards autoscaling, so frame everything explicitly
    extent = np.vstack([profile.outer] + [[start, end, np.add(np.add(start, end) / 2, offset)]
                                           for _, start, end, offset in dimensions])
    low, high = extent.min(axis=0) - 0.08 * span, extent.max(axis=0) + 0.08 * span
    ax.set_xlim(low[0], high[0])
    ax.set_ylim(low[1], high[1])
    ax.set_aspect("equal")
    ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    folder = Path((argv or sys.argv[1:] or ["docs/img"])[0])
    folder.mkdir(parents=True, exist_ok=True)
    for kind, params, stem, dimensions in DRAWINGS:
        draw(kind, params, dimensions, folder / f"section_{stem}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
