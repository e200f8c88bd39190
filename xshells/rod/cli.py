"""``xshells demo``: the rod demo (replaced by a linkage deployment later)."""
from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help="run the bundled demo and write its figures")
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.set_defaults(func=_demo)


def _demo(args) -> int:
    from . import demo

    result = demo.run(args.out)
    for row in result["discrete"]:
        print(f"elastica, {row['edges']:3d} edges: end force error {row['force_error']:.3%}, midpoint height error {row['height_error']:.3%}")
    print(f"wrote {args.out}/elastica.png and {args.out}/elastica.json in {result['time_s']:.1f} s")
    return 0
