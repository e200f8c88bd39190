"""Grasshopper Hops: the JSON protocol and a small HTTP server, on the standard library.

Hops (McNeel's Grasshopper component for remote solves) asks a server two
things:

* ``GET /<component>``: the component's metadata (``Description``,
  ``Inputs``, ``Outputs``, each parameter with its ``Name``, ``ParamType``,
  ``AtLeast``/``AtMost`` and ``Default``); ``GET /`` lists them all;
* ``POST /solve`` (the payload's ``pointer`` names the component) or
  ``POST /<component>``: a payload ``{"values": [{"ParamName": …,
  "InnerTree": {"{0}": [{"type": …, "data": …}]}}], "modelunits": …,
  "absolutetolerance": …}`` whose items carry numbers and text as JSON and
  geometry as RhinoCommon JSON (``CommonObject.Encode`` in rhino3dm). The
  reply has the same shape, with ``errors`` and ``warnings``.

Why by hand rather than the ``ghhops-server`` package (1.5.5, the latest):
it installs, but a handler's exception reaches Grasshopper as the error
"Exception occured in handler:" followed by a Python traceback, its HTTP
server answers a failed solve with HTTP 500, a payload that is not JSON
raises inside the request thread (the client gets no answer), and it prints
every input to standard output. Here every failure is one line in the
reply's ``errors``, with HTTP 200, as Hops shows it on the component.

Solves are serialized (one at a time: they are CPU-bound and share the
command line's settings) and cached by a hash of their inputs, so
Grasshopper's re-solves of unchanged inputs are answered from memory.
"""
from __future__ import annotations

import hashlib
import json
import math
import sys
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Callable

from ..errors import InputError

#: the largest request body read (a design's curves are kilobytes; a Content-Length of 1e15 made the
#: handler raise MemoryError and answer nothing)
MAX_BODY = 256 * 1024 * 1024

#: Hops parameter kinds: (ParamType in the metadata, result type of the items we send)
KINDS = {
    "Curve": ("Curve", "Rhino.Geometry.Curve"),
    "Mesh": ("Mesh", "Rhino.Geometry.Mesh"),
    "Point": ("Point", "Rhino.Geometry.Point3d"),
    "Number": ("Number", "System.Double"),
    "Integer": ("Integer", "System.Int32"),
    "Text": ("Text", "System.String"),
    "Boolean": ("Boolean", "System.Boolean"),
}
CACHE_SIZE = 32


@dataclass(frozen=True)
class Param:
    """One input or output of a component. ``many``: a list (Grasshopper list access), else one item."""

    name: str
    kind: str
    description: str
    many: bool = False
    default: object = None
    optional: bool = False

    def metadata(self) -> dict:
        param_type, result_type = KINDS[self.kind]
        d = {"Name": self.name, "Nickname": self.name, "Description": self.description, "ParamType": param_type,
             "ResultType": result_type, "AtLeast": 0 if (self.optional or self.default is not None) else 1,
             "AtMost": 2147483647 if self.many else 1}
        if self.default is not None:
            d["Default"] = self.default
        return d


@dataclass(frozen=True)
class Component:
    """A Hops component: ``solve(inputs, context)`` takes the decoded inputs by name and returns the
    outputs by name (geometry as rhino3dm objects); it raises :class:`InputError` for bad input."""

    uri: str
    name: str
    description: str
    inputs: tuple
    outputs: tuple
    solve: Callable = field(repr=False)

    def metadata(self) -> dict:
        return {"Uri": self.uri, "Name": self.name, "Nickname": self.name, "Description": self.description,
                "Category": "xshells", "Subcategory": "X-shells", "Inputs": [p.metadata() for p in self.inputs],
                "Outputs": [p.metadata() for p in self.outputs]}


@dataclass(frozen=True)
class Context:
    """What the payload says of the Grasshopper document: its unit system and absolute tolerance."""

    units: str = "Millimeters"
    tolerance: float = 0.001


# decoding ---------------------------------------------------------------------------------------------

def _point(d) -> tuple:
    return float(d["X"]), float(d["Y"]), float(d["Z"])


def decode_item(item: dict, param: Param):
    """One item of an input tree: a Python number, bool or str, or a rhino3dm geometry object."""
    if not isinstance(item, dict) or not isinstance(item.get("type", ""), str):
        raise InputError(f"input {param.name!r}: malformed item {str(item)[:60]!r} (expected {{type, data}})")
    try:
        return _decode_item(item, param)
    except (KeyError, TypeError, AttributeError, ValueError, OverflowError) as exc:
        if isinstance(exc, InputError):
            raise
        # a struct without its fields ({"From": {...}} without "To", a point without "Z", "X": "a")
        raise InputError(f"input {param.name!r}: an item could not be read ({type(exc).__name__}: {exc})") from None


def _decode_item(item: dict, param: Param):
    import rhino3dm

    kind, raw = item.get("type", ""), item.get("data")
    try:
        data = json.loads(raw) if isinstance(raw, str) else raw
    except json.JSONDecodeError:
        data = raw  # Hops sends plain text for some strings
    where = f"input {param.name!r}"
    if param.kind in ("Number", "Integer"):
        if isinstance(data, bool):  # JSON true is not 1
            raise InputError(f"{where}: expected a number, got {raw!r}")
        try:
            v = float(data)
        except (TypeError, ValueError):
            raise InputError(f"{where}: expected a number, got {raw!r}") from None
        if param.kind == "Integer":
            if not math.isfinite(v) or v != int(v):
                raise InputError(f"{where}: expected a whole number, got {v:g}")
            return int(v)
        return v
    if param.kind == "Boolean":
        if isinstance(data, bool):
            return data
        if str(data).lower() in ("true", "false"):
            return str(data).lower() == "true"
        raise InputError(f"{where}: expected True or False, got {raw!r}")
    if param.kind == "Text":
        return str(data)
    if kind.endswith("Line") and isinstance(data, dict) and "From" in data:  # Rhino.Geometry.Line, a struct
        return rhino3dm.LineCurve(rhino3dm.Point3d(*_point(data["From"])), rhino3dm.Point3d(*_point(data["To"])))
    if isinstance(data, list) and len(data) >= 2 and all(isinstance(p, dict) and "X" in p for p in data):
        pl = rhino3dm.Point3dList()  # Rhino.Geometry.Polyline, a struct: its points
        for p in data:
            pl.Add(*_point(p))
        return rhino3dm.PolylineCurve(pl)
    if kind.endswith("Point3d") and isinstance(data, dict) and "X" in data:
        return rhino3dm.Point3d(*_point(data))
    if isinstance(data, dict):
        try:
            g = rhino3dm.CommonObject.Decode(data)
        except Exception:  # rhino3dm raises bare errors for malformed archives
            g = None
        if g is not None:
            return g
    raise InputError(f"{where}: could not read a {param.kind.lower()} from an item of type {kind or 'unknown'}")


def decode_inputs(payload: dict, component: Component) -> dict:
    """The payload's values by input name (lists for list inputs), defaults filled in."""
    values = payload.get("values")
    if not isinstance(values, list):
        raise InputError("malformed Hops payload: no list of 'values'")
    by_name = {}
    for tree in values:
        if (not isinstance(tree, dict) or not isinstance(tree.get("ParamName"), str)
                or not isinstance(tree.get("InnerTree", {}), dict)):
            raise InputError("malformed Hops payload: each value needs a 'ParamName' (a name) and an 'InnerTree'")
        by_name[tree["ParamName"]] = tree
    known = {p.name for p in component.inputs}
    unknown = sorted(set(by_name) - known)
    if unknown:
        raise InputError(f"{component.name}: unknown input {unknown[0]!r} (inputs: {', '.join(sorted(known))})")
    out = {}
    for p in component.inputs:
        items = []
        tree = by_name.get(p.name)
        if tree is not None:
            for path in sorted(tree.get("InnerTree", {})):  # all branches, flattened, in path order
                branch = tree["InnerTree"][path]
                if not isinstance(branch, list):
                    raise InputError(f"malformed Hops payload: branch {path} of {p.name!r} is not a list")
                items.extend(decode_item(it, p) for it in branch)
        if not items:
            if p.default is None and not p.optional:
                raise InputError(f"{component.name}: input {p.name!r} is empty")
            out[p.name] = ([] if p.many else None) if p.default is None else p.default
        elif p.many:
            out[p.name] = items
        elif len(items) > 1:
            raise InputError(f"{component.name}: input {p.name!r} takes one item, got {len(items)}")
        else:
            out[p.name] = items[0]
    return out


def encode_item(value, param: Param) -> dict:
    if param.kind in ("Curve", "Mesh"):
        return {"type": f"Rhino.Geometry.{type(value).__name__}", "data": json.dumps(value.Encode())}
    if param.kind == "Point":
        return {"type": "Rhino.Geometry.Point3d", "data": json.dumps({"X": value[0], "Y": value[1], "Z": value[2]})}
    py = {"Number": float, "Integer": int, "Text": str, "Boolean": bool}[param.kind]
    return {"type": KINDS[param.kind][1], "data": json.dumps(py(value))}


def encode_outputs(outputs: dict, component: Component) -> list:
    values = []
    for p in component.outputs:
        v = outputs.get(p.name)
        items = (list(v) if p.many else [v]) if v is not None else []
        values.append({"ParamName": p.name, "InnerTree": {"{0}": [encode_item(x, p) for x in items]}})
    return values


# the service ------------------------------------------------------------------------------------------

class HopsService:
    """Metadata and cached, serialized solves for a set of components (no HTTP: see :func:`serve`)."""

    def __init__(self, components, log=None):
        self.components = {c.uri: c for c in components}
        self._cache: OrderedDict[str, str] = OrderedDict()
        self._lock = threading.Lock()
        self.log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))

    def metadata(self, path: str) -> tuple[int, str]:
        path = "/" + path.strip("/")
        if path == "/":
            return 200, json.dumps([c.metadata() for c in self.components.values()])
        c = self.components.get(path.lower())
        if c is None:
            return 404, json.dumps({"values": [], "errors": [f"no component {path} (components: "
                                                              f"{', '.join(sorted(self.components))})"]})
        return 200, json.dumps(c.metadata())

    def solve(self, path: str, body: bytes) -> str:
        """The reply to a POST (always a Hops schema, errors in ``errors``)."""
        try:
            payload = json.loads(body.decode("utf-8") if isinstance(body, (bytes, bytearray)) else body)
            if not isinstance(payload, dict):
                raise ValueError("not an object")
        except (ValueError, UnicodeDecodeError) as exc:
            return self._error(f"malformed Hops payload: not JSON ({exc})")
        except RecursionError:
            return self._error("malformed Hops payload: JSON nested too deeply")
        path = "/" + path.strip("/")
        pointer = payload.get("pointer") if path == "/solve" else path
        if not isinstance(pointer, str):
            return self._error("malformed Hops payload: POST /solve needs a 'pointer' naming the component", payload)
        uri = "/" + pointer.strip("/").lower()
        comp = self.components.get(uri)
        if comp is None:
            return self._error(f"no component {uri} (components: {', '.join(sorted(self.components))})", payload)
        units = payload.get("modelunits") or "Millimeters"
        tol = payload.get("absolutetolerance")
        if tol is None:  # not sent: Rhino's default for a millimetre document. A 0 sent is refused below (it became 0.001)
            tol = 0.001
        key = hashlib.sha256(json.dumps([uri, units, tol, payload.get("values")], sort_keys=True,
                                        default=str).encode()).hexdigest()
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                self.log(f"{comp.name}: unchanged inputs, answered from the cache")
                return self._cache[key]
            t0 = time.perf_counter()
            try:
                from .read import RHINO_UNITS_TO_MM

                if not isinstance(units, str) or units not in RHINO_UNITS_TO_MM:
                    raise InputError(f"the Grasshopper document's units {units!r} are not supported "
                                     f"(supported: {', '.join(RHINO_UNITS_TO_MM)})")
                try:
                    tol = float(tol)
                except (TypeError, ValueError):
                    raise InputError(f"malformed Hops payload: absolutetolerance {tol!r} is not a number") from None
                if not (math.isfinite(tol) and tol > 0):
                    raise InputError(f"malformed Hops payload: absolutetolerance {tol!r} is not a positive length")
                inputs = decode_inputs(payload, comp)
                self.log(f"{comp.name}: solving")
                outputs = comp.solve(inputs, Context(units=units, tolerance=tol))
                warnings = outputs.pop("_warnings", [])
                reply = json.dumps({"pointer": pointer, "modelunits": units, "values": encode_outputs(outputs, comp),
                                    "warnings": list(warnings), "errors": []})
            except InputError as exc:
                self.log(f"{comp.name}: {exc}")
                return self._error(str(exc), payload)
            except KeyboardInterrupt:
                raise
            except Exception as exc:  # a bug of ours: one line to Grasshopper, the traceback to the server log
                import traceback

                self.log("".join(traceback.format_exception(exc)))
                return self._error(f"{comp.name}: internal error ({type(exc).__name__}: {exc}); the server log "
                                   "has the details", payload)
            self.log(f"{comp.name}: solved in {time.perf_counter() - t0:.2f} s")
            self._cache[key] = reply
            while len(self._cache) > CACHE_SIZE:
                self._cache.popitem(last=False)
            return reply

    @staticmethod
    def _error(message: str, payload: dict | None = None) -> str:
        p = payload if isinstance(payload, dict) else {}
        return json.dumps({"pointer": p.get("pointer"), "values": [], "warnings": [], "errors": [message]})


def make_server(service: HopsService, host: str = "127.0.0.1", port: int = 5000):
    """A threading HTTP server for ``service`` (not started: call ``serve_forever``)."""
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    class Handler(BaseHTTPRequestHandler):
        timeout = 60  # seconds a request may take to arrive: a Content-Length beyond its body waited forever

        def log_message(self, fmt, *args):  # one line per request, to the service's log
            service.log(f"{self.address_string()} {fmt % args}")

        def _reply(self, status: int, text: str):
            data = text.encode("utf-8")
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def _get(self) -> tuple[int, str]:
            path = self.path.split("?")[0]
            if path.rstrip("/") == "/solve":
                return 405, json.dumps({"errors": ["POST a Hops payload to /solve"]})
            return service.metadata(path)

        def do_GET(self):
            self._reply(*self._get())

        def do_HEAD(self):  # GET's status and headers, no body (it answered 200 for a path that GET calls 404)
            status, text = self._get()
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(text.encode("utf-8"))))
            self.end_headers()

        def _not_served(self):
            self.send_response(405)
            self.send_header("Allow", "GET, HEAD, POST")
            data = json.dumps({"values": [], "warnings": [], "errors": [
                f"{self.command} is not served: GET / lists the components, POST /solve solves one"]}).encode("utf-8")
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _not_served

        def send_error(self, code, message=None, explain=None):
            """http.server's own errors (an unknown method, a malformed request line) as JSON, not its HTML page."""
            short, long = self.responses.get(code, ("Error", ""))
            text = message or short
            self.log_error("code %d, message %s", code, text)
            self.send_response(code, short)
            self.send_header("Connection", "close")
            body = b""
            if code >= 200 and code not in (204, 304) and self.command != "HEAD":
                body = json.dumps({"values": [], "warnings": [], "errors": [f"{code} {text}" + (f": {explain}" if explain else "")]}).encode("utf-8")
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            if body:
                self.wfile.write(body)

        def do_POST(self):
            try:
                length = int(self.headers.get("Content-Length") or 0)
            except ValueError:
                length = 0
            if length > MAX_BODY:  # reading it would take the memory first
                self._reply(413, json.dumps({"values": [], "errors": [f"a request of {length} bytes, more than the "
                                                                       f"{MAX_BODY} this server reads"], "warnings": []}))
                return
            body = self.rfile.read(length) if length > 0 else b""
            self._reply(200, service.solve(self.path.split("?")[0], body))

    return ThreadingHTTPServer((host, port), Handler)
