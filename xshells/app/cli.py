"""``xshells app``: start the interactive design tool in the browser."""
from __future__ import annotations

import os

from ..errors import InputError, check_input_file


def register(subparsers) -> None:
    p = subparsers.add_parser("app", help="the interactive design tool in the browser",
                              description="Edit a flat X-shell layout, deploy it interactively and export it for fabrication. "
                                          "Serves on 127.0.0.1 (this machine only) unless --host is given.")
    p.add_argument("input", nargs="?", help="a design (.obj, .msh, .3dm) or a case file (.json); default: a 6 × 6 grid")
    p.add_argument("--port", type=int, default=8080, help="port (default 8080; the next free one if taken)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1; 0.0.0.0 exposes it to the network)")
    p.add_argument("--out", default="xshells_app_out", help="folder for exports (default: xshells_app_out)")
    p.set_defaults(func=_app)


def start(input_path: str | None = None, *, host: str = "127.0.0.1", port: int = 8080, out_dir: str = "xshells_app_out",
          project=None):
    """Build the session and the server; returns the :class:`~xshells.app.ui.App` (already serving).

    The server listens first, so the browser loads the page while the design
    is read (unless ``project``, read already, is given); the solver is
    imported and run later, on the session's worker.
    """
    if not 0 < port < 65536:
        raise InputError(f"--port must be 1 to 65535, got {port}")
    check_host(host)
    from .ui import App, serve

    server = serve(host, port)
    try:
        from .loading import grid_project, open_path
        from .session import Session

        if project is None:
            project = open_path(input_path) if input_path else grid_project(6, 6)
        return App(Session(project, out_dir=out_dir), server=server)
    except BaseException:
        server.stop()
        raise


#: Seconds the name resolver may take over --host: a name it has not answered for by then is refused.
RESOLVE_TIMEOUT_S = 5.0


def check_host(host: str) -> None:
    """Refuse, in one line and at once, a ``--host`` this machine cannot listen on.

    viser takes any error of its server for a port in use and tries the next one, a thousand times
    (each with its own name lookup), and then waits for ever for a server that never started: an
    unresolvable name, or the address of another machine, hung the command.
    """
    import socket
    import threading

    found = {}

    def resolve():  # in a thread: getaddrinfo has no timeout of its own
        try:
            found["address"] = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)[0]
        except OSError as exc:
            found["error"] = exc.strerror or str(exc)
        except UnicodeError:  # Python's IDNA encoding of the name refused it
            found["error"] = "not a host name: a part between dots is empty or longer than 63 characters"

    lookup = threading.Thread(target=resolve, daemon=True, name="xshells-resolve")
    lookup.start()
    lookup.join(RESOLVE_TIMEOUT_S)
    if lookup.is_alive():
        raise InputError(f"--host {host}: the name resolver gave no answer in {RESOLVE_TIMEOUT_S:g} s")
    if "error" in found:
        raise InputError(f"--host {host}: cannot resolve it ({found['error']})")
    family, kind, proto, _, address = found["address"]
    with socket.socket(family, kind, proto) as probe:
        try:
            probe.bind(address)  # port 0: any free one; whether this machine has the address is what counts
        except OSError as exc:
            raise InputError(f"--host {host}: cannot listen there ({exc.strerror}): give an address of this "
                             "machine, such as 127.0.0.1 or 0.0.0.0") from None


def _app(args) -> int:
    import time

    if args.input:
        check_input_file(args.input)
    if args.input and not os.path.isfile(args.input):
        raise InputError(f"{args.input}: no such file")
    project = None
    if args.input:  # a bad file gets its one line here, not after the server's banner (tens of ms sooner)
        from .loading import open_path

        project = open_path(args.input)
    app = start(args.input, host=args.host, port=args.port, out_dir=args.out, project=project)
    print(f"xshells app: http://{args.host}:{app.server.get_port()}  (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    finally:
        app.stop()
