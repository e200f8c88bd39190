"""``xshells section``: stiffness of a beam cross-section.

    xshells section PROFILE.json
    xshells section contour.obj --young 2600 --poisson 0.35
    xshells section rectangle 10 7 --young 20000 --poisson 0.3 --plot psi.png
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from ..errors import InputError
from .profiles import PARAM_NAMES

FILE_SUFFIXES = (".json", ".obj", ".msh")


def register(subparsers) -> None:
    """Add the ``section`` subcommand to an argparse subparsers object."""
    types = "; ".join(f"{kind}: {names}" for kind, names in PARAM_NAMES.items())
    parser = subparsers.add_parser(
        "section",
        help="stiffness of a beam cross-section (area, inertia, torsion constant)",
        description="Compute stretching, bending and twisting stiffness of a beam profile and print them as JSON.",
        epilog=f"Parametric types and their parameters: {types}. See docs/sections.md.",
    )
    parser.add_argument("profile", nargs="+", metavar="PROFILE",
                        help="a cross-section JSON, an .obj/.msh contour, or TYPE followed by its parameters")
    parser.add_argument("--young", type=float, help="Young's modulus E (overrides the file's)")
    parser.add_argument("--poisson", type=float, help="Poisson's ratio, in (-1, 0.5) (overrides the file's)")
    parser.add_argument("--density", type=float, default=1.0, help="mass per unit volume (default 1)")
    parser.add_argument("--stiff-axis", default=None,
                        help="D1 or D2: the material axis that gets the larger bending stiffness; "
                             "or an angle in radians of d1 from the profile's x axis (default: profile axes)")
    parser.add_argument("--rtol", type=float, default=1e-5,
                        help="refine until the torsion constant changes by less than this (default 1e-5)")
    parser.add_argument("--plot", metavar="FILE.png", help="draw the mesh coloured by the warping function")
    parser.add_argument("-o", "--output", metavar="FILE.json", help="write the JSON here instead of stdout")
    parser.set_defaults(func=run)


def _stiff_axis(value):
    if value is None or value.strip().upper() in ("D1", "D2"):
        return value
    try:
        return float(value)
    except ValueError:
        raise InputError(f"--stiff-axis must be D1, D2 or an angle in radians, got {value!r}") from None


def material_from_args(args):
    """Build the :class:`~xshells.section.material.Material` described by parsed arguments."""
    # imported here so that registering the subcommand does not load scikit-fem
    from .io import load_section
    from .material import Material
    from .profiles import make_profile

    first, rest = args.profile[0], args.profile[1:]
    if Path(first).suffix.lower() in FILE_SUFFIXES or Path(first).is_file():
        if rest:
            raise InputError(f"unexpected arguments after {first}: {' '.join(rest)}")
        profile, E, nu = load_section(first, young=args.young, poisson=args.poisson)
    else:
        params = []
        for token in rest:
            try:
                params.append(float(token))
            except ValueError:
                raise InputError(f"{first}: parameter {token!r} is not a number") from None
        profile = make_profile(first, params)
        if args.young is None or args.poisson is None:
            raise InputError(f"{first}: give --young and --poisson for a profile typed on the command line")
        E, nu = args.young, args.poisson
    if not args.rtol > 0:
        raise InputError(f"--rtol must be positive, got {args.rtol:g}")
    return Material(profile, E, nu, density=args.density, stiff_axis=_stiff_axis(args.stiff_axis), rtol=args.rtol)


def _temp_beside(path: Path) -> tuple[str, str]:
    """``(target, temp)``: the file that writing ``path`` replaces and a new empty file in its folder.

    Raises InputError in one line for a missing folder, a device or folder as ``path``, or a folder
    that takes no new files.
    """
    from ..io.export import output_target

    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise InputError(f"{path}: folder {directory} does not exist")
    # a link is written through, and a device (-o /dev/null) or a folder (-o .) refused: the rename
    # replaced /dev/full with a file
    target = output_target(path)
    try:
        fd, temp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=os.path.dirname(target))
    except OSError as exc:  # a folder that takes no new files (/proc, read-only)
        raise InputError(f"{path}: cannot write there ({exc.strerror or exc})") from None
    os.close(fd)
    return target, temp


def check_output_path(path) -> None:
    """Refuse an output that could not be written, before the (minutes long) computation rather than after."""
    _, temp = _temp_beside(Path(path))
    os.remove(temp)


def _write_atomically(path: Path, write) -> None:
    """Call ``write(temp_path)`` then move the result onto ``path``, so readers never see half a file."""
    from ..io.export import replace_with

    target, temp = _temp_beside(Path(path))
    try:
        write(temp)
        replace_with(temp, target)
    finally:
        if os.path.exists(temp):
            os.remove(temp)


def plot_warping(material, path) -> None:
    """Save a PNG of the cross-section mesh coloured by ψ (paper Fig. 4)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.tri import Triangulation

    solution = material.section.torsion.solution
    mesh = solution.basis.mesh
    # P2 vertex dofs come first, so psi[:nvertices] are vertex values; curved
    # (quadratic) meshes also store edge midpoints in p, after the vertices.
    nv = mesh.nvertices
    tri = Triangulation(mesh.p[0, :nv], mesh.p[1, :nv], mesh.t[:3].T)
    fig, ax = plt.subplots(figsize=(5, 4), dpi=100)
    shaded = ax.tripcolor(tri, solution.psi[: mesh.nvertices], shading="gouraud", cmap="coolwarm")
    ax.triplot(tri, color="k", linewidth=0.15, alpha=0.5)
    fig.colorbar(shaded, ax=ax, label="warping function ψ")
    ax.set_aspect("equal")
    ax.set_xlabel("x (about centroid)")
    ax.set_ylabel("y")
    ax.set_title(f"{Path(material.profile.name).name}: J = {material.torsion_constant:.6g}", fontsize=9)
    fig.tight_layout()
    _write_atomically(Path(path), lambda temp: fig.savefig(temp, format="png"))
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    """Handler for ``xshells section``; returns an exit code."""
    if args.plot and Path(args.plot).suffix.lower() != ".png":
        raise InputError(f"--plot {args.plot}: the picture must be a .png file")
    # a bad --plot or -o was found after the JSON had been printed (and exited 2 with it on stdout)
    for option, value in (("-o", args.output), ("--plot", args.plot)):
        if value:
            try:
                check_output_path(value)
            except InputError as exc:
                raise InputError(f"{option} {exc}") from None
    material = material_from_args(args)
    text = json.dumps(material.summary(), indent=2)
    if args.output:
        _write_atomically(Path(args.output), lambda temp: Path(temp).write_text(text + "\n", encoding="utf-8"))
    else:
        sys.stdout.write(text + "\n")
    if args.plot:
        plot_warping(material, args.plot)
    return 0
