"""``xshells hops``: xshells as Grasshopper components, through Hops."""
from __future__ import annotations

from ..errors import InputError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "hops", help="serve Deploy, Optimize, Sparsify, Analyze and Inverse as Grasshopper Hops components",
        description="Serves xshells to Grasshopper's Hops component: point a Hops component at "
                    "http://HOST:PORT/deploy (or /optimize, /sparsify, /analyze, /inverse). Each solve runs the "
                    "command of that name on the component's inputs, in the document's units; unchanged inputs are "
                    "answered from a cache. Progress and errors go to this terminal. Stop with Ctrl-C.")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0 opens it to the network)")
    p.add_argument("--port", type=int, default=5000, help="port (default 5000, Hops' default)")
    p.set_defaults(func=_hops)


def _hops(args) -> int:
    from .components import components
    from .hops import HopsService, make_server

    if not 0 < args.port < 65536:
        raise InputError(f"--port {args.port}: a port is between 1 and 65535")
    service = HopsService(components())
    try:
        server = make_server(service, args.host, args.port)
    except OSError as exc:
        raise InputError(f"cannot listen on {args.host}:{args.port} ({exc.strerror or exc})") from None
    host, port = server.server_address[:2]
    print(f"xshells hops: serving {', '.join(c.name for c in service.components.values())} on "
          f"http://{host}:{port}/ (Ctrl-C stops)", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0
