"""Grasshopper Hops: metadata over HTTP, a Deploy solve from a Hops payload that agrees with ``xshells deploy``,
the document's units, the cache, and one-line errors for malformed payloads."""
import json
import threading
import urllib.request

import numpy as np
import pytest

from data_paths import EXAMPLES
from xshells.cli import main
from xshells.io import read_design
from xshells.rhino.components import components
from xshells.rhino.hops import HopsService, make_server

rhino3dm = pytest.importorskip("rhino3dm")

SCALE = 200.0  # the bundled irregular grid, made ~100 mm a segment so that the default 10 × 7 section is slender
OPTIONS = {"Angle": ("System.Double", 80.0), "Subdivision": ("System.Int32", 4), "Steps": ("System.Int32", 10)}


def _grid():
    d = read_design(EXAMPLES / "nonuniform_linkage.obj")
    return np.asarray(d.vertices, float) * SCALE, np.asarray(d.edges)


def _payload(per_mm=1.0, units="Millimeters", pointer="/deploy", **extra):
    """What Grasshopper sends: lines as RhinoCommon JSON (rhino3dm's Encode), numbers as JSON text."""
    V, E = _grid()
    items = []
    for a, b in E:
        c = rhino3dm.LineCurve(rhino3dm.Point3d(*(V[a] * per_mm)), rhino3dm.Point3d(*(V[b] * per_mm)))
        items.append({"type": "Rhino.Geometry.LineCurve", "data": json.dumps(c.Encode())})
    values = [{"ParamName": "Lines", "InnerTree": {"{0}": items}}]
    for name, (kind, v) in {**OPTIONS, **extra}.items():
        values.append({"ParamName": name, "InnerTree": {"{0}": [{"type": kind, "data": json.dumps(v)}]}})
    return {"pointer": pointer, "modelunits": units, "absolutetolerance": 1e-6 * per_mm, "values": values}


def _outputs(reply):
    out = {}
    for v in reply["values"]:
        items = v["InnerTree"]["{0}"]
        decoded = []
        for it in items:
            data = json.loads(it["data"])
            geometry = it["type"].startswith("Rhino.Geometry.") and it["type"] != "Rhino.Geometry.Point3d"
            decoded.append(rhino3dm.CommonObject.Decode(data) if geometry else data)
        out[v["ParamName"]] = decoded
    return out


def read_polylines_obj(path):
    """The ``l`` records of an OBJ as point arrays."""
    V, lines = [], []
    for raw in open(path):
        parts = raw.split()
        if parts and parts[0] == "v":
            V.append([float(x) for x in parts[1:4]])
        elif parts and parts[0] == "l":
            lines.append([int(i) - 1 for i in parts[1:]])
    V = np.array(V)
    return [V[idx] for idx in lines]


def _points(curve):
    pl = curve.TryGetPolyline()
    return np.array([[pl[i].X, pl[i].Y, pl[i].Z] for i in range(pl.Count)])


@pytest.fixture(scope="module")
def server():
    logs = []
    service = HopsService(components(), log=logs.append)
    httpd = make_server(service, "127.0.0.1", 0)  # a free loopback port
    t = threading.Thread(target=httpd.serve_forever, daemon=True)
    t.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}", service, logs
    httpd.shutdown()
    httpd.server_close()


def _get(url):
    with urllib.request.urlopen(url) as r:
        return r.status, json.loads(r.read())


def _post(url, body):
    req = urllib.request.Request(url, data=body if isinstance(body, bytes) else json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json"}, method="POST")
    with urllib.request.urlopen(req) as r:
        return r.status, json.loads(r.read())


@pytest.fixture(scope="module")
def deployed(server):
    url, _, _ = server
    return _post(url + "/solve", _payload())


def test_it_binds_loopback_by_default(server):
    url, _, _ = server
    assert url.startswith("http://127.0.0.1:")
    from xshells.cli import build_parser

    args = build_parser().parse_args(["hops"])
    assert args.host == "127.0.0.1" and args.port == 5000


def test_metadata_of_every_component(server):
    url, _, _ = server
    status, listing = _get(url + "/")
    assert status == 200
    assert sorted(c["Name"] for c in listing) == ["Analyze", "Deploy", "Inverse", "Optimize", "Sparsify"]
    for c in listing:
        status, meta = _get(url + c["Uri"])
        assert status == 200
        assert meta["Description"] and meta["Inputs"] and meta["Outputs"]
        for p in meta["Inputs"] + meta["Outputs"]:
            assert {"Name", "ParamType", "AtLeast", "AtMost"} <= set(p)
    names = [p["Name"] for p in _get(url + "/deploy")[1]["Inputs"]]
    assert names[:1] == ["Lines"] and {"Section", "Young", "Angle", "Steps", "Direction"} <= set(names)


def test_deploy_agrees_with_xshells_deploy(deployed, tmp_path):
    status, reply = deployed
    assert status == 200 and reply["errors"] == [], reply["errors"]
    out = _outputs(reply)
    assert out["Stable"] == [True]
    lines = [_points(c) for c in out["Centerlines"]]
    # the same lines through the command line, in the .3dm the component writes: read back from it, the
    # design's vertices come in the curves' order, not the OBJ's. (From an OBJ of the same lines, the same
    # equilibrium in another variable order: the deployment agreed to 2.2e-9 of the span, within the
    # solver's tolerance along the soft modes but not bit for bit.)
    import rhino3dm

    from xshells.rhino.components import Context, _write_design

    V, E = _grid()
    model = tmp_path / "grid.3dm"
    _write_design(str(model), [rhino3dm.LineCurve(rhino3dm.Point3d(*V[a]), rhino3dm.Point3d(*V[b])) for a, b in E],
                  Context(units="Millimeters", tolerance=1e-6))
    code = main(["deploy", str(model), "--angle", "80", "--subdivision", "4", "--steps", "10", "--out",
                 str(tmp_path / "cli"), "--no-progress"])
    assert code == 0
    ref = read_polylines_obj(tmp_path / "cli" / "deployed_centerlines.obj")
    assert len(ref) == len(lines)
    span = np.ptp(np.vstack(ref), axis=0).max()
    assert max(np.abs(a - b).max() for a, b in zip(lines, ref)) <= 1e-9 * span
    r = json.loads((tmp_path / "cli" / "result.json").read_text())
    assert out["Energy"][0] == pytest.approx(r["deployed"]["energy"], rel=1e-12)
    assert out["Torque"][0] == pytest.approx(r["deployed"]["torque"], rel=1e-12)
    assert len(out["Beams"]) == 1 and len(out["Beams"][0].Vertices) > 0


def test_the_documents_units_in_and_out(server, deployed):
    url, _, _ = server
    _, mm = deployed
    status, m = _post(url + "/solve", _payload(per_mm=1e-3, units="Meters"))
    assert status == 200 and m["errors"] == [], m["errors"]
    a, b = _outputs(mm), _outputs(m)
    assert b["Energy"][0] == pytest.approx(a["Energy"][0], rel=1e-9)  # the same design: solved in mm both times
    pa = np.vstack([_points(c) for c in a["Centerlines"]])
    pb = np.vstack([_points(c) for c in b["Centerlines"]])
    assert np.abs(pb * 1e3 - pa).max() <= 1e-9 * np.ptp(pa, axis=0).max()  # returned in metres


def test_unchanged_inputs_come_from_the_cache(server, deployed):
    url, _, logs = server
    _, first = deployed
    n = len(logs)
    status, again = _post(url + "/deploy", _payload())  # the component's own URI, as newer Hops posts
    assert status == 200 and again["values"] == first["values"]
    assert any("from the cache" in line for line in logs[n:])


@pytest.mark.parametrize("body, words", [
    (b"{not json", "not JSON"),
    ({"values": []}, "pointer"),
    ({"pointer": "/nothing", "values": []}, "no component /nothing"),
    ({"pointer": "/deploy", "values": "x"}, "list of 'values'"),
    ({"pointer": "/deploy", "values": [{"ParamName": "Lines"}], "modelunits": "Parsecs"}, "units 'Parsecs'"),
    ({"pointer": "/deploy", "values": [{"ParamName": "Bogus", "InnerTree": {}}]}, "unknown input 'Bogus'"),
    ({"pointer": "/deploy", "values": []}, "input 'Lines' is empty"),
    # a re-check's payloads: no reply at all (RecursionError), internal errors (TypeError), silently accepted
    (b"[" * 100000 + b"]" * 100000, "nested too deeply"),
    ({"pointer": "/deploy", "values": [{"ParamName": "Lines"}], "modelunits": ["Meters"]}, "units ['Meters']"),
    ({"pointer": "/deploy", "values": [{"ParamName": [5], "InnerTree": {}}]}, "'ParamName' (a name)"),
    ({"pointer": "/deploy", "values": [{"ParamName": "Lines"}], "absolutetolerance": -1}, "not a positive length"),
    ({"pointer": "/deploy", "values": [{"ParamName": "Lines"}], "absolutetolerance": "nan"}, "not a positive length"),
    # 0 was taken for 0.001 without a word
    ({"pointer": "/deploy", "values": [{"ParamName": "Lines"}], "absolutetolerance": 0}, "absolutetolerance 0.0 is not"),
])
def test_malformed_payloads_get_one_line(server, body, words):
    url, _, _ = server
    status, reply = _post(url + "/solve", body)
    assert status == 200 and reply["values"] == []
    assert len(reply["errors"]) == 1 and words in reply["errors"][0], reply["errors"]
    assert "Traceback" not in reply["errors"][0] and "\n" not in reply["errors"][0]


def test_a_bad_input_to_the_command_is_the_components_error(server):
    url, _, _ = server
    status, reply = _post(url + "/solve", _payload(Direction=("System.String", "sideways")))
    assert status == 200 and reply["errors"] == ["input 'Direction': up or down, got 'sideways'"]
    status, reply = _post(url + "/solve", _payload(Angle=("System.String", "wide")))
    assert reply["errors"] == ["input 'Angle': expected a number, got '\"wide\"'"], reply["errors"]
    status, reply = _post(url + "/solve", _payload(Section=("System.String", "rectangle:ten,7")))
    assert len(reply["errors"]) == 1 and "rectangle:ten,7" in reply["errors"][0], reply["errors"]


@pytest.mark.parametrize("extra, words", [
    # an internal error (int(nan)); the value read as an option ("--angle: expected one argument"); a
    # negative angle run at the default angle without a word; true read as 1; a huge --sample filled the memory
    ({"Steps": ("System.Int32", "NaN")}, "input 'Steps': expected a whole number"),
    ({"Steps": ("System.Int32", True)}, "input 'Steps': expected a number"),
    ({"Angle": ("System.Double", -5.0)}, "input 'Angle': must be 0 (the default) or positive, got -5"),
    ({"Sample": ("System.Int32", 1000000000)}, "input 'Sample' must be from 1 to 1000 segments per curve"),
    # the command's own checks name the component's inputs, not its options or the server's temporary files
    ({"Steps": ("System.Int32", 0)}, "input 'Steps' must be from 1 to 100000, got 0"),
    ({"Young": ("System.Double", -5.0)}, "input 'Young' must be a positive Young's modulus"),
    ({"Section": ("System.String", "")}, "input 'Section': empty"),  # ran with the default section
    ({"Section": ("System.String", "contour:x.json")}, "not a file"),  # was read on the server
])
def test_bad_numbers_get_one_line_and_no_default_in_their_place(server, extra, words):
    url, _, _ = server
    status, reply = _post(url + "/solve", _payload(**extra))
    assert status == 200 and len(reply["errors"]) == 1 and words in reply["errors"][0], reply["errors"]


def test_command_errors_are_put_in_the_components_words(tmp_path):
    from xshells.rhino.components import as_inputs

    tmp = str(tmp_path / "xshells-hops-abc")
    design = tmp + "/design.3dm"
    assert as_inputs(f"{design}: the design has no joint", tmp) == "input 'Lines': the design has no joint"
    assert as_inputs(f"could not read {tmp}/surface.3dm", tmp) == "could not read input 'Surface'"
    assert as_inputs("--max-fit 200%: must lie between 0 and 100%", tmp) == "input 'MaxFit' 200%: must lie between 0 and 100%"
    assert as_inputs("--max-iters must be at least 1 (see xshells optimize --help)", tmp) == "input 'MaxIters' must be at least 1"
    assert as_inputs(f"cannot write {tmp}/out/x", tmp) == "cannot write the server's work folder/out/x"
    assert as_inputs("--unknown-option and --out stay", tmp) == "--unknown-option and --out stay"


def test_a_struct_without_its_fields_and_a_value_starting_with_a_dash():
    from xshells.errors import InputError
    from xshells.rhino.components import _joined
    from xshells.rhino.hops import Param, decode_item

    line = Param("Lines", "Curve", "")
    for data in ({"From": {"X": 0, "Y": 0, "Z": 0}}, {"From": {"X": 0, "Y": 0}, "To": {"X": 1, "Y": 0, "Z": 0}}):
        with pytest.raises(InputError, match=r"^input 'Lines': an item could not be read"):  # KeyError before
            decode_item({"type": "Rhino.Geometry.Line", "data": json.dumps(data)}, line)
    with pytest.raises(InputError, match=r"^input 'Lines': malformed item"):
        decode_item("abc", line)
    assert _joined(["deploy", "d.3dm", "--angle", "-inf", "--load", "--help", "--out", "o"]) == \
        ["deploy", "d.3dm", "--angle=-inf", "--load=--help", "--out=o"]


def test_unknown_get_is_404_with_a_message(server):
    url, _, _ = server
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(url + "/nothing")
    assert e.value.code == 404 and "no component /nothing" in json.loads(e.value.read())["errors"][0]


def test_head_answers_as_get_does(server):
    # HEAD answered 200 for a path that GET calls 404
    import http.client

    url, _, _ = server
    for path, code in (("/nothing", 404), ("/deploy", 200), ("/solve", 405)):
        conn = http.client.HTTPConnection(url.split("//")[1], timeout=10)
        conn.request("HEAD", path)
        r = conn.getresponse()
        assert (r.status, r.getheader("Content-Type"), r.read()) == (code, "application/json", b"")
        conn.close()


def test_no_component_has_an_input_and_an_output_of_one_name():
    # Sparsify's input and output were both "Actuators"
    for c in components():
        meta = c.metadata()
        assert not {i["Name"] for i in meta["Inputs"]} & {o["Name"] for o in meta["Outputs"]}, c.name


@pytest.mark.parametrize("method, code, words", [
    ("PUT", 405, "PUT is not served"), ("DELETE", 405, "DELETE is not served"),
    ("FOO", 501, "501 Unsupported method ('FOO')"),  # http.server's own error: its HTML page before
])
def test_other_methods_get_a_json_error(server, method, code, words):
    import http.client

    url, _, _ = server
    conn = http.client.HTTPConnection(url.split("//")[1], timeout=10)
    conn.request(method, "/solve", body=b"{}")
    r = conn.getresponse()
    assert r.status == code and r.getheader("Content-Type") == "application/json"
    assert words in json.loads(r.read())["errors"][0]
    conn.close()


@pytest.mark.parametrize("pointer, extra, expect", [
    ("/sparsify", {"Actuators": ("System.Int32", 4)}, {"Actuated": 4, "Torques": 4}),
    ("/optimize", {"MaxIters": ("System.Int32", 2)}, {"Layout": 170}),
    ("/analyze", {"Supports": ("System.String", "lowest:4"), "Loads": ("System.String", "self-weight"),
                  "Density": ("System.Double", 1.9e-9)}, {"MaxStress": 1}),
])
def test_the_other_components_solve_the_same_lines(server, pointer, extra, expect):
    url, _, _ = server
    status, reply = _post(url + "/solve", _payload(pointer=pointer, **extra))
    assert status == 200 and reply["errors"] == [], reply["errors"]
    out = _outputs(reply)
    assert len(out["Centerlines"]) == 170 and len(out["Beams"]) == 1  # one polyline per segment of the grid
    for name, n in expect.items():
        assert len(out[name]) == n, name
    if pointer in ("/sparsify", "/optimize"):  # the command printed and recorded how it read the .3dm
        assert any("units Millimeters" in w for w in reply["warnings"]), reply["warnings"]
    if pointer == "/sparsify":
        assert all(t > 0 for t in out["Torques"])
    if pointer == "/analyze":
        assert out["MaxStress"][0] > 0


def test_inverse_wants_a_mesh(server):
    url, _, _ = server
    line = rhino3dm.LineCurve(rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(1, 0, 0))
    body = {"pointer": "/inverse", "values": [{"ParamName": "Surface", "InnerTree": {"{0}": [
        {"type": "Rhino.Geometry.LineCurve", "data": json.dumps(line.Encode())}]}}]}
    _, reply = _post(url + "/solve", body)
    assert reply["errors"] == ["input 'Surface': a mesh is needed, got a LineCurve"]


def test_the_command_serves_until_interrupted(tmp_path):
    import signal
    import socket
    import subprocess
    import sys
    import time

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "xshells.cli", "hops", "--port", str(port)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 60
        while True:
            try:
                status, meta = _get(f"http://127.0.0.1:{port}/deploy")
                break
            except OSError:
                assert proc.poll() is None and time.time() < deadline, proc.communicate()
                time.sleep(0.2)
        assert status == 200 and meta["Name"] == "Deploy"
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert f"http://127.0.0.1:{port}/" in out and "Traceback" not in err


def test_a_port_in_use_is_one_line(capsys):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        code = main(["hops", "--port", str(s.getsockname()[1])])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot listen on 127.0.0.1" in err[0]


def test_a_polyline_struct_is_read_as_a_polyline_curve():
    from xshells.rhino.hops import Param, decode_item

    pts = [{"X": 0.0, "Y": 0.0, "Z": 0.0}, {"X": 1.0, "Y": 0.0, "Z": 0.0}, {"X": 1.0, "Y": 2.0, "Z": 0.0}]
    c = decode_item({"type": "Rhino.Geometry.Polyline", "data": json.dumps(pts)}, Param("Lines", "Curve", "", many=True))
    assert isinstance(c, rhino3dm.PolylineCurve) and _points(c).tolist() == [[0, 0, 0], [1, 0, 0], [1, 2, 0]]
