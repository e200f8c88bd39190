"""``xshells inverse``: a flat X-shell that deploys onto a given surface."""
from __future__ import annotations

from ..errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "inverse", help="design a flat X-shell that deploys onto a target surface",
        description="Target-first design: lays a beam net on the surface, flattens and closes it, deploys it, and "
                    "optimizes its rest lengths (paper eq. 5) while a load that first holds it on the surface is let go. "
                    "Writes a case that `xshells deploy` reproduces. Units follow the surface (lengths) and the "
                    "material (Young's modulus): the bundled data use mm and MPa.")
    p.add_argument("surface", help="the target: a surface mesh (OBJ, PLY, STL, gmsh .msh or Rhino .3dm; triangles, quads or convex polygons) in design units (a .3dm states its own and is read in mm)")
    p.add_argument("--spacing", type=float, help="joint spacing along the beams (default: 1/12 of the surface's diagonal, or a quarter of its width where that is less)")
    p.add_argument("--angle", type=float, default=90.0, help="deployed average opening angle, degrees, in (20, 160) (default 90)")
    p.add_argument("--orientation", type=float, default=0.0,
                   help="turns the beam families on the surface, degrees (0: their bisector along the surface's longest axis)")
    p.add_argument("--flat-angle", type=float, default=20.0, help="opening angle of the flat, closed layout, degrees (default 20)")
    p.add_argument("--grading", type=float, default=0.0,
                   help="grades the automatic net, degrees: its crossing angle runs from ANGLE+GRADING on its middle "
                        "line to ANGLE-GRADING at its sides, and its joint spacings vary with it (default 0: evenly "
                        "spaced joints; -25 reaches the spherical cap closest, see docs/inverse.md)")
    p.add_argument("--beams", choices=("auto", "even", "geodesic", "fanned"), default="auto",
                   help="how the automatic net lays its beams: geodesic (two families of the surface's geodesics), "
                        "even (joints evenly spaced along a scissor map's directions), fanned (straight flat beams "
                        "whose angle varies across each family, so the layout buckles; the fan is screened unless "
                        "--fan gives it), or auto (the default: even, the best screened fan, and geodesics where "
                        "their flat layout closes, the best design kept; see docs/inverse.md)")
    p.add_argument("--fan", type=float,
                   help="with --beams fanned: the fan K, in (-0.5, 0.5): the flat layout opens by FLAT_ANGLE*(1+K) on "
                        "its middle lines and FLAT_ANGLE*(1-K) at its ends (default: screened)")
    p.add_argument("--no-free-ends", action="store_true",
                   help="end each beam of the automatic net at its last joint instead of continuing it to the "
                        "surface's boundary as a free end")
    p.add_argument("--net", help="a 3D quad net (OBJ: quad faces or beam lines) drawn on or near the surface, used "
                                 "instead of the automatic one")
    p.add_argument("--direction", choices=("up", "down"), default="up",
                   help="which way the flat layout buckles (written into the case; default up; a design that deploys "
                        "onto the surface only the other way is kept with the other direction, named in the case)")
    p.add_argument("--material", help="TYPE:P1,P2,... (e.g. rectangle:10,7) or a cross-section JSON file (default rectangle 10 × 7)")
    p.add_argument("--young", type=float, help="Young's modulus (default 20000, as in the paper, MPa)")
    p.add_argument("--poisson", type=float, help="Poisson's ratio (default 0.3)")
    p.add_argument("--subdivision", type=int, default=8, help="edges per segment (default 8)")
    p.add_argument("--steps", type=int, default=30, help="deployment increments (default 30)")
    # default: InverseOptions.max_iters (not imported here: the parser is built for every command)
    p.add_argument("--max-iters", type=int,
                   help="design-optimization iterations once the holding load is gone (default 80; "
                        "the design is checked every 10, and the best kept)")
    p.add_argument("--buckling", type=float,
                   help="weight of the planar-buckling penalty: asks the layout's planar opening to the angle to be "
                        "unstable, so that the deployment from flat buckles (default: off, and a design whose deployment "
                        "stays in the plane is designed again with weight 1, the better kept; 0: never)")
    p.add_argument("--tries", type=int, default=1,
                   help="designs of each net, the fit weight doubled from one to the next; the best is kept "
                        "(default 1; each try costs a whole design's time)")
    p.add_argument("--no-refine", action="store_true",
                   help="at the default spacing, keep the first design even where it misses the bar narrowly "
                        "(default: such a design is designed again on a net 3/4 as fine, and the better kept)")
    p.add_argument("--no-heavier", action="store_true",
                   help="keep the design even where it misses the bar, or meets it but not within 0.5%% mean and 2%% "
                        "max (default: its net is designed again with the fit weight x16, then x4 where "
                        "x16 is not that close either, and the best kept)")
    p.add_argument("--no-reseat", action="store_true",
                   help="never re-seat (default: where no design checked is within 0.5%% mean and 2%% max once the load "
                        "is let go, the optimization goes on from the state the design's own deployment from flat "
                        "reaches, up to 2 rounds of 30 iterations)")
    p.add_argument("--no-deploy-guide", action="store_true",
                   help="never guide a deployment (default: where a stage's deployment from flat is not within 0.5%% "
                        "mean and 2%% max and the state the optimization tracks fits better, the deployed shell is held "
                        "on that state and let go, and kept so where that fits better; its case then names "
                        "deploy_guide.txt)")
    p.add_argument("--no-clearance", action="store_true",
                   help="let the optimization bring the flat layout's beams of one family closer than a beam's width "
                        "(default: a barrier keeps them apart, since a stage design whose flat beams overlap is refused)")
    p.add_argument("--polish", type=float, default=None,
                   help="after the last stage, 20 more iterations with the fit weight times this, from the design "
                        "reached; the design whose own deployment fits best is kept (default 2; 0: off)")
    p.add_argument("--workers", type=int, help="processes for the fan screen, the tries of one net and the auto candidates, side by side, and for each design's stage checks beside its optimization (default: the cores, at most 2; 1: one after the other)")
    p.add_argument("--force", action="store_true", help="allow nets of more than 5,000 segments, up to what fits in memory")
    p.add_argument("--out", default="inverse_out",
                   help="output folder (default inverse_out; a reused one loses an earlier run's candidates/, refined/, heavier/, "
                        "tries/, buckling/ and result.json at the start)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars or notes on stderr (warnings and errors still print)")
    p.set_defaults(func=_inverse)


def _inverse(args) -> int:
    from ..deploy.case import check_counts, material_spec_from_option
    from .run import InverseOptions, run_inverse

    check_counts(args.subdivision, args.steps)
    if args.max_iters is not None and args.max_iters < 1:
        raise InputError(f"--max-iters must be at least 1, got {args.max_iters}")
    if args.buckling is not None and not (args.buckling >= 0 and args.buckling < float("inf")):
        raise InputError(f"--buckling must be a non-negative number, got {args.buckling}")
    if args.polish is not None and not (args.polish == 0 or 1 < args.polish < float("inf")):
        raise InputError(f"--polish must be 0 (off) or a factor above 1, got {args.polish}")
    spec = material_spec_from_option(args.material, args.young, args.poisson)
    opts = InverseOptions(spacing=args.spacing, angle=args.angle, orientation=args.orientation, flat_angle=args.flat_angle,
                          direction=args.direction, subdivision=args.subdivision, steps=args.steps,
                          force=args.force, grading=args.grading, beams=args.beams, fan=args.fan,
                          free_ends=not args.no_free_ends, workers=args.workers, tries=args.tries,
                          refine=not args.no_refine, heavier=not args.no_heavier, deploy_guide=not args.no_deploy_guide,
                          clearance=not args.no_clearance,
                          **({} if args.max_iters is None else {"max_iters": args.max_iters}),
                          **({} if args.buckling is None else {"buckling": args.buckling}))
    from dataclasses import replace

    if args.polish is not None:
        opts = replace(opts, guide=replace(opts.guide, polish=args.polish))
    if args.no_reseat:
        opts = replace(opts, reseat=replace(opts.reseat, rounds=0))
    try:
        r = run_inverse(args.surface, args.out, spec, opts, net_path=args.net, progress=not args.no_progress)
    except KeyboardInterrupt as exc:  # the generic handler prints "interrupted" and exits 130; with it, what DIR holds
        exc.kept = kept_on_interrupt(args.out)
        raise
    if r["status"] in ("complete", "missed", "invalid"):
        print(f"{r['segments']} segments, {r['joints']} joints: fit mean {100 * r['fit_mean']:.2f}%, "
              f"max {100 * r['fit_max']:.2f}% of the diagonal; coverage {100 * r['coverage']:.1f}% "
              f"({r['time_s']:.0f} s)")
    print(f"  {r['status']}: {r['message']}")
    if r["status"] == "missed" and r.get("fit_max_at") is not None:
        x, y, z = r["fit_max_at"]
        print(f"  farthest: joint {r['fit_max_joint']}, {r['fit_max_distance']:.4g} off the surface at "
              f"({x:.4g}, {y:.4g}, {z:.4g}) in its frame (fit.png, inverse.3dm)")
    if r.get("deployed_angle_min_deg") is not None:
        print(f"  joints open to {r['deployed_angle_min_deg']:.1f}–{r['deployed_angle_max_deg']:.1f}° deployed "
              f"(average {r['angle_deg']:g}°), {r['min_flat_angle_deg']:.1f}–{r['flat_angle_max_deg']:.1f}° flat")
    if r.get("beams"):
        print(f"  beams: {r['beams']} ({r.get('beams_reason', '')})")
    if r.get("direction_asked") and r.get("direction") != r["direction_asked"]:
        print(f"  direction: {r['direction']} (asked {r['direction_asked']}; buckling {r['direction_asked']}, this "
              f"design deploys to the mirror image of the surface); the case says {r['direction']}")
    if r.get("chosen_stage_reseat"):
        k, rounds = r["chosen_stage_reseat"], r.get("reseated") or []
        done = next((d for d in rounds if d.get("round") == k), {})
        before = (f" (the state it tracked then fitted {100 * done['tracked_fit_mean']:.2f}% mean, "
                  f"{100 * done['tracked_fit_max']:.2f}% max, where no design's own deployment had come within 0.5% / 2%)"
                  if "tracked_fit_mean" in done else "")
        print(f"  re-seated: the kept design comes from re-seating round {k}, optimized from its own deployment from "
              f"flat{before}")
    guided = r.get("deploy_guide")
    if r.get("chosen_stage_guided") and guided:
        print(f"  guided: case.json names deploy_guide.txt, the state the optimization tracked; held there and let "
              f"go, the shell stays {100 * guided['released_rms']:.2g}% of its span from it (RMS), "
              f"{100 * guided['moved']:.2g}% from the equilibrium its deployment from flat reaches alone (largest "
              f"joint){'' if guided['held'] else '; NOT followed: ' + guided['note']}")
    if r.get("tries"):
        t = r["tries"]
        figures = ", ".join(f"{d['beta']:g}: " + (f"{100 * d['fit_mean']:.2f}%" if d.get("fit_mean") is not None else d["status"])
                            for d in t["designs"])
        print(f"  tries: kept try {t['kept']} of {len(t['designs'])} (fit weight {figures})")
    if r.get("refined"):
        f = r["refined"]
        other = f["refined"] if f["kept"] == "default" else f["default"]
        figures = (f"fit mean {100 * other['fit_mean']:.2f}%, max {100 * other['fit_max']:.2f}%"
                   if other.get("fit_mean") is not None else other.get("message", other.get("status", "")))
        print(f"  refined: {f['why']}; " + (
            f"the finer net (spacing {f['spacing']:.4g}) did better and is kept; the default's: {figures}"
            if f["kept"] == "refined" else f"the finer net (spacing {f['spacing']:.4g}) did not do better "
                                           f"({figures}); the default's design is kept"))
    if r.get("heavier"):
        h = r["heavier"]
        figures = ", ".join(f"x{d['factor']:g}: " + (f"{100 * d['fit_mean']:.2f}%" if d.get("fit_mean") is not None
                                                     else d.get("status", "")) for d in h["designs"])
        print(f"  heavier fit weight: {h['why']}; " + (f"kept x{h['kept']} (fit mean: {figures}; x1: "
                                                       f"{100 * h['default']['fit_mean']:.2f}%)" if h["kept"] != "default"
                                                       else f"none did better ({figures}); the first design is kept"))
    verified = r["status"] in ("complete", "missed", "invalid")  # "stopped", "interrupted": written, not deployed
    print(f"  outputs in {args.out}/" + (f" (xshells deploy {args.out}/case.json reproduces the deployment)"
                                         if verified else " (the design was not verified)"))
    return 0 if r["status"] == "complete" else 1


def kept_on_interrupt(out: str) -> str:
    """What ``out`` holds after Ctrl-C, in a few words: the kept design's status and fit, or that none was finished
    (a run clears an earlier run's result.json first, so one that is there is this run's)."""
    import json
    import os

    try:
        with open(os.path.join(out, "result.json")) as fh:
            r = json.load(fh)
    except (OSError, ValueError):
        return f"no design was finished: {out}/ holds none of this run"
    status = r.get("status", "?")
    fit = (f", fit mean {100 * r['fit_mean']:.2f}%, max {100 * r['fit_max']:.2f}% of the diagonal"
           if isinstance(r.get("fit_mean"), (int, float)) and isinstance(r.get("fit_max"), (int, float)) else "")
    what = "verified" if status in ("complete", "missed", "invalid") else "written, not verified"
    return f"{out}/ holds the best design so far ({status}{fit}; {what}: see {out}/result.json)"
