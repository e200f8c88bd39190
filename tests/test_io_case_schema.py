"""The case-file schema (xshells.io.case_schema), clean errors on every command, and nothing half-written."""
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import jsonschema
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from xshells.cli import main
from xshells.errors import InputError
from xshells.io.case_schema import CaseFile, json_schema, markdown, validate_case
from xshells.io.design import read_design

from data_paths import DATA, EXAMPLES, REPO, needs_data

DOCS = REPO / "docs"
BUNDLED_CASES = sorted(EXAMPLES.rglob("case.json"))


# ------------------------------------------------------------------ the schema and its published forms
def test_the_published_schema_and_page_are_generated_from_the_models():
    assert json.loads((DOCS / "case.schema.json").read_text()) == json_schema(), \
        "regenerate: python -m xshells.io.case_schema docs/case.schema.json docs/case.md"
    assert (DOCS / "case.md").read_text() == markdown()


@pytest.mark.parametrize("path", BUNDLED_CASES, ids=lambda p: p.parent.name)
def test_the_published_schema_validates_every_bundled_case(path):
    spec = json.loads(path.read_text())
    jsonschema.validate(spec, json_schema())
    validate_case(spec, str(path))


def _doc_examples():
    for md in sorted(DOCS.glob("*.md")):
        text = md.read_text()
        for block in text.split("```json")[1:]:
            body = block.split("```", 1)[0]
            data = json.loads(body)
            if isinstance(data, dict) and "file" in data:  # a case file
                yield md.name, data


@pytest.mark.parametrize("name,data", list(_doc_examples()), ids=lambda v: v if isinstance(v, str) else "")
def test_the_published_schema_validates_the_docs_examples(name, data):
    jsonschema.validate(data, json_schema())
    validate_case(data, name)


@pytest.mark.parametrize("data,match", [
    ({"file": "manta_ray.obj", "angle_deg": "ninety"}, "key 'angle_deg' = \"ninety\": Input should be a valid number"),
    ({"file": 5, "angle_deg": 60}, "key 'file' = 5: Input should be a valid string"),
    ({"file": "a.obj", "angle_dg": 60}, "unknown key 'angle_dg' (did you mean 'angle_deg'?)"),
    ({"file": "a.obj", "material": {"Young": 2000}}, "unknown key 'material.Young'"),
    ({"file": "a.obj", "angle_deg": 200}, "less than 180"),
    ({"file": "a.obj", "angle_deg": float("nan")}, "angle_deg"),
    ({"file": "a.obj", "subdivision": 2.5}, "valid integer"),
    ({"file": "a.obj", "steps": True}, "valid integer"),
    ({"file": "a.obj", "angle_deg": 60, "open_by_deg": 10}, "give one of angle_deg, angle_rad, open_by_deg"),
    ({"file": "a.obj", "material": {"type": "hexagon"}}, "unknown cross-section type 'hexagon'"),
    ({"file": "a.obj", "material": {"type": "contour"}}, "needs contour_file"),
    ({"file": "a.obj", "material": {"params": [10, -7]}}, "positive finite lengths"),
    ({"file": "a.obj", "material": {"nu": 0.7}}, "less than 0.5"),
    ({"file": "a.obj", "material": {"type": "ellipse"}}, "type 'ellipse' needs its dimensions in 'params'"),
    ({"file": "a.obj", "material": {"type": "CONTOUR"}}, "needs contour_file"),
    # the count of dimensions, named with the file and the key (it was "rectangle: rectangle takes 2 ...",
    # from the section when the material was built, naming neither)
    ({"file": "a.obj", "material": {"params": [5]}},
     "case.json: key 'material': rectangle takes 2 parameters (width, height), got 1"),
    ({"file": "a.obj", "material": {"type": "plus", "params": [1, 2]}},
     "case.json: key 'material': + takes 4 parameters (a, b, t1, t2), got 2"),
    ({"angle_deg": 60}, "missing key 'file'"),
    ([1, 2], "a case is a JSON object"),
])
def test_bad_case_objects_get_one_line_naming_the_key(data, match):
    with pytest.raises(InputError) as e:
        validate_case(data, "case.json")
    msg = str(e.value)
    assert msg.startswith("case.json: ") and match in msg and "\n" not in msg, msg


def test_a_material_without_dimensions_is_the_default_rectangle_and_contour_is_case_insensitive(tmp_path):
    """docs/case.md: the default material is a rectangle 10 × 7, and a grade's values are overridden by
    the keys given: a grade alone (or an E alone) once failed with "rectangle takes 2 parameters, got 0"."""
    from xshells.deploy.case import material_from_spec

    plain = material_from_spec({"type": "rectangle", "params": [10, 7], "E": 30000})
    for spec in ({"E": 30000}, {"type": "Rect", "E": 30000}):
        m = material_from_spec(validate_case({"file": "a.obj", "material": spec}, "case.json").material.model_dump(exclude_none=True))
        assert m.section.area == plain.section.area and m.E == plain.E
    contour = tmp_path / "square.obj"
    contour.write_text("v 0 0 0\nv 4 0 0\nv 4 2 0\nv 0 2 0\nl 1 2\nl 2 3\nl 3 4\nl 4 1\n")
    m = material_from_spec({"type": "Contour", "contour_file": str(contour), "E": 2000})
    assert abs(m.section.area - 8.0) < 1e-6


def test_a_good_case_keeps_its_values():
    c = validate_case({"file": "d.obj", "material": {"type": "Rectangle", "E": 2000, "params": [4, 1.5]}, "angle_deg": 60})
    assert isinstance(c, CaseFile) and c.angle_deg == 60.0 and c.material.E == 2000.0 and c.subdivision == 10


# ------------------------------------------------------------------ the CLI: one line, non-zero exit
def _cli(capsys, argv):
    code = main(argv)
    err = capsys.readouterr().err.strip()
    return code, err


@pytest.mark.parametrize("spec,match", [
    ({"file": "manta_ray.obj", "angle_deg": "ninety"}, "angle_deg"),
    ({"file": 5, "angle_deg": 60}, "key 'file' = 5"),
])
@pytest.mark.parametrize("command", ["deploy", "optimize", "sparsify"])
def test_issue_inputs_are_one_line_on_every_command(tmp_path, capsys, spec, match, command):
    (tmp_path / "manta_ray.obj").write_bytes((EXAMPLES / "manta_ray.obj").read_bytes())
    (tmp_path / "c.json").write_text(json.dumps(spec))
    code, err = _cli(capsys, [command, str(tmp_path / "c.json"), "--out", str(tmp_path / "o"), "--no-progress"])
    assert code == 2 and match in err and len(err.splitlines()) == 1, err


def test_an_output_folder_that_cannot_be_created_is_refused_before_work(tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    for out in ("/proc/nope", str(tmp_path / "afile"), str(tmp_path / "afile" / "sub")):
        t0 = time.perf_counter()
        code, err = _cli(capsys, ["deploy", str(EXAMPLES / "manta_ray.obj"), "--out", out, "--no-progress"])
        assert code == 2 and "--out" in err and len(err.splitlines()) == 1, err
        assert time.perf_counter() - t0 < 5  # refused at once, not after the deployment


def test_a_huge_coordinate_is_named_not_reported_as_a_zero_length_segment(tmp_path, capsys):
    (tmp_path / "big.obj").write_text("v 0 0 0\nv 1 0 0\nv 1e308 1 0\nv 0 1 0\nl 1 2\nl 2 3\nl 3 4\nl 4 1\nl 1 3\n")
    code, err = _cli(capsys, ["deploy", str(tmp_path / "big.obj"), "--out", str(tmp_path / "o"), "--no-progress"])
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "line 3" in err and "1e+308" in err and "zero-length" not in err, err


def test_an_internal_error_is_one_line_with_its_traceback_in_error_log(tmp_path, capsys, monkeypatch):
    import xshells.deploy.run as deploy_run

    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(deploy_run, "run_deployment", broken)
    argv = ["deploy", str(EXAMPLES / "manta_ray.obj"), "--out", str(tmp_path / "o"), "--no-progress"]
    code, err = _cli(capsys, argv)
    assert code == 3 and len(err.splitlines()) == 1 and "ZeroDivisionError: a bug" in err and "--debug" in err, err
    log = (tmp_path / "o" / "error.log").read_text()
    assert "Traceback" in log and "ZeroDivisionError" in log
    with pytest.raises(ZeroDivisionError):
        main(argv + ["--debug"])


# ------------------------------------------------------------------ nothing half-written
def _complete(path: Path) -> bool:
    data = path.read_bytes()
    if path.suffix == ".png":
        return data.startswith(b"\x89PNG") and data.rstrip().endswith(b"IEND\xaeB`\x82")
    if path.suffix == ".json":
        json.loads(data)
        return True
    return True


def test_a_deploy_killed_with_sigterm_leaves_only_complete_files(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "xshells.cli", "deploy", str(EXAMPLES / "manta_ray.obj"), "--angle", "93",
                             "--out", str(out), "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)
    deadline = time.time() + 120
    while time.time() < deadline and not (out / "flat.png").exists():  # the flat state is written: deploying now
        time.sleep(0.05)
    time.sleep(0.5)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode != 0
    files = sorted(p for p in out.iterdir())
    assert not [p.name for p in files if ".tmp" in p.name or p.name.startswith(".")], files
    assert all(_complete(p) for p in files)
    assert (out / "result.json").exists(), (proc.returncode, [p.name for p in files], err.decode()[-2000:])
    r = json.loads((out / "result.json").read_text())
    assert r["status"] == "interrupted"
    assert b"Traceback" not in err, err.decode()


# ------------------------------------------------------------------ fuzz: a clean error or a valid result, nothing else
def _accepted(data) -> tuple[bool, bool]:
    """(validate_case accepts, the published schema accepts)."""
    try:
        validate_case(data, "case.json")
        ours = True
    except InputError:
        ours = False
    return ours, jsonschema.Draft202012Validator(json_schema()).is_valid(data)


material_values = st.fixed_dictionaries({}, optional={
    "type": st.sampled_from(["rectangle", "RECT", " ellipse ", "I", "i-beam", "L", "+", "plus", "contour", "Contour",
                             "hexagon", "", "circle"]),
    "params": st.lists(st.sampled_from([10.0, 7.0, 0.5, 0.0, -3.0]), max_size=4),
    "contour_file": st.sampled_from(["sec.json", None]),
    "grade": st.sampled_from(["softwood-c24", "GFRP-E23", " birch-plywood", "oak", None]),
    "E": st.sampled_from([20000.0, -1.0, None]),
})
angle_values = st.fixed_dictionaries({"file": st.just("a.obj")}, optional={
    "angle_deg": st.sampled_from([60.0, None, 200.0]), "angle_rad": st.sampled_from([1.2, None]),
    "open_by_deg": st.sampled_from([30.0, None]), "material": material_values})


@settings(max_examples=300, deadline=None)
@given(angle_values)
def test_the_published_schema_accepts_exactly_what_the_validator_accepts(data):
    """Cross-key rules (one angle key, contour_file with contour only, dimensions for all but the
    rectangle, known types and grades, positive lengths) hold in the published schema too."""
    ours, published = _accepted(data)
    assert ours == published, (data, ours, published)


@pytest.mark.parametrize("data", [
    {"file": "a.obj", "angle_deg": 60, "open_by_deg": 10},
    {"file": "a.obj", "material": {"type": "contour"}},
    {"file": "a.obj", "material": {"type": "rectangle", "contour_file": "s.json"}},
    {"file": "a.obj", "material": {"type": "ellipse"}},
    {"file": "a.obj", "material": {"type": "hexagon", "params": [1, 2]}},
    {"file": "a.obj", "material": {"params": [10, -7]}},
    {"file": "a.obj", "material": {"grade": "oak"}},
    {"file": "a.obj", "material": {"params": [5]}},
    {"file": "a.obj", "material": {"type": "Ellipse", "params": [1, 2, 3]}},
])
def test_the_published_schema_refuses_the_cross_key_mistakes(data):
    assert _accepted(data) == (False, False)


KEYS = list(CaseFile.model_fields) + ["angle_dg", "materials", "E", ""]
json_values = st.recursive(st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=True)
                           | st.text(max_size=8), lambda inner: st.lists(inner, max_size=3)
                           | st.dictionaries(st.text(max_size=6), inner, max_size=3), max_leaves=6)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(st.sampled_from(KEYS), json_values, max_size=6) | json_values)
def test_fuzz_case_objects(data):
    try:
        validate_case(data, "fuzz.json")
    except InputError as exc:
        assert "\n" not in str(exc)


GOOD_OBJ = "v 0 0 0\nv 100 0 0\nv 100 100 0\nv 0 100 0\nv 50 50 0\nl 1 5\nl 5 3\nl 2 5\nl 5 4\n"
obj_tokens = st.sampled_from(["v", "l", "f", "vn", "#", "1", "2", "-1", "0", "1e308", "nan", "inf", "x", "1/2", "\n", " ",
                              "\t", "\x00", "é", "99", "1.5", "l 1 1", "v 1 2"])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.one_of(
    st.lists(obj_tokens, max_size=40).map(lambda t: " ".join(t).encode("utf-8", "replace")),
    st.tuples(st.integers(0, len(GOOD_OBJ)), st.binary(max_size=12)).map(
        lambda c: GOOD_OBJ.encode()[:c[0]] + c[1] + GOOD_OBJ.encode()[c[0]:]),
    st.binary(max_size=200),
), st.sampled_from([".obj", ".msh"]))
def test_fuzz_design_files(tmp_path_factory, content, ext):
    path = tmp_path_factory.mktemp("fuzz") / f"d{ext}"
    path.write_bytes(content)
    try:
        read_design(path)
    except InputError as exc:
        assert "\n" not in str(exc)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.tuples(st.integers(0, len(GOOD_OBJ)), st.sampled_from(["", " 0", "\nv 1 2 3", "\nl 1 2", "x", "\nl 2 3"])),
       st.dictionaries(st.sampled_from(["angle_deg", "subdivision", "steps", "material"]),
                       st.one_of(st.integers(-5, 200), st.floats(-1, 200), st.text(max_size=3),
                                 st.just({"type": "rectangle", "params": [4, 1.5], "E": 2000})), max_size=3))
def test_fuzz_deploy_gives_a_clean_error_or_a_run(tmp_path_factory, edit, extra):
    folder = tmp_path_factory.mktemp("deploy")
    at, text = edit
    (folder / "d.obj").write_text(GOOD_OBJ[:at] + text + GOOD_OBJ[at:])
    case = {"file": "d.obj", "subdivision": 3, "steps": 2, "angle_deg": 40,
            "material": {"type": "rectangle", "params": [4, 1.5], "E": 2000}, **extra}
    (folder / "c.json").write_text(json.dumps(case))
    import io
    from contextlib import redirect_stderr, redirect_stdout

    err = io.StringIO()
    with redirect_stderr(err), redirect_stdout(io.StringIO()):
        code = main(["deploy", str(folder / "c.json"), "--out", str(folder / "o"), "--no-progress"])
    assert code in (0, 1, 2), err.getvalue()  # 1: a run that ended short of its angle, and says why
    if code == 2:
        assert len(err.getvalue().strip().splitlines()) == 1, err.getvalue()
    else:
        status = json.loads((folder / "o" / "result.json").read_text())["status"]
        assert status == ("complete" if code == 0 else "stopped")


def test_the_fuzzed_deploy_base_case_is_a_valid_run(tmp_path, capsys):
    (tmp_path / "d.obj").write_text(GOOD_OBJ)
    (tmp_path / "c.json").write_text(json.dumps({"file": "d.obj", "subdivision": 3, "steps": 2, "angle_deg": 40,
                                                 "material": {"type": "rectangle", "params": [4, 1.5], "E": 2000}}))
    assert main(["deploy", str(tmp_path / "c.json"), "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    assert json.loads((tmp_path / "o" / "result.json").read_text())["status"] == "complete"


@pytest.mark.parametrize("argv,match", [
    (["deploy", "M", "--steps", "0"], "--steps must be from 1 to 100000, got 0"),
    (["deploy", "M", "--subdivision", "0"], "--subdivision must be from 3 to 1000"),
    (["optimize", "M", "--steps", "0"], "--steps must be from 1 to 100000"),
    (["sparsify", "M", "--subdivision", "2"], "--subdivision must be from 3 to 1000"),
    (["demo", "--steps", "0"], "--steps must be from 1 to 100000"),
    # the case schema's upper bounds hold on the command line too (there, the run simply never ended)
    (["deploy", "M", "--subdivision", "100000"], "--subdivision must be from 3 to 1000 edges per segment, got 100000"),
    (["deploy", "M", "--steps", "1000000"], "--steps must be from 1 to 100000, got 1000000"),
    (["optimize", "M", "--min-angle", "nan"], "--min-angle must be a finite angle in degrees"),
])
def test_zero_counts_are_refused_not_replaced_by_the_default(tmp_path, capsys, argv, match):
    argv = [str(EXAMPLES / "manta_ray.obj") if a == "M" else a for a in argv]
    code, err = _cli(capsys, argv + ["--out", str(tmp_path / "o"), "--no-progress"])
    assert code == 2 and match in err and len(err.splitlines()) == 1, err


@needs_data
def test_every_entry_of_the_papers_cases_json_is_a_valid_case():
    cases = json.loads((DATA / "cases.json").read_text())["cases"]
    for c in cases:
        jsonschema.validate(c, json_schema())
        validate_case(c, c["name"])


def test_a_stop_swallowed_by_a_finalizer_still_stops_the_deployment(tmp_path, monkeypatch):
    # SIGTERM raises KeyboardInterrupt wherever Python is; inside a __del__ Python drops it. The flag the
    # handler sets stops the deployment at its next step all the same.
    from xshells.deploy.case import material_from_spec
    from xshells.deploy.run import run_deployment
    from xshells.errors import STOP

    monkeypatch.setattr(STOP, "requested", True)
    with pytest.raises(KeyboardInterrupt):
        run_deployment(str(EXAMPLES / "quad.obj"), material_from_spec({"type": "rectangle", "params": [10, 7],
                                                                      "E": 20000, "nu": 0.3}),
                       out_dir=str(tmp_path / "out"), steps=5, progress=False)
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert r["status"] == "interrupted"


QUAD_MATERIAL = {"type": "rectangle", "params": [10, 7], "E": 20000, "nu": 0.3}


def test_a_stop_while_the_last_files_are_written_waits_for_result_json(tmp_path, monkeypatch):
    # The signal handler calls STOP.request(); landing while the deployed files are written, it must
    # neither cut result.json off nor be lost.
    import xshells.deploy.run as run
    from xshells.deploy.case import material_from_spec
    from xshells.errors import STOP

    monkeypatch.setattr(STOP, "requested", False)
    write = run._write_deployed_outputs

    def write_then_signal(*args):
        STOP.request()  # what the handler does; deferred here, so nothing is raised yet
        write(*args)

    monkeypatch.setattr(run, "_write_deployed_outputs", write_then_signal)
    with pytest.raises(KeyboardInterrupt):
        run.run_deployment(str(EXAMPLES / "quad.obj"), material_from_spec(QUAD_MATERIAL), out_dir=str(tmp_path / "out"),
                           steps=3, progress=False)
    r = json.loads((tmp_path / "out" / "result.json").read_text())
    assert r["status"] == "complete"  # the deployment itself finished before the stop
    assert (tmp_path / "out" / "deployed.obj").exists() and (tmp_path / "out" / "deployment.csv").exists()


def test_a_stop_turned_into_another_error_by_a_library_still_counts_as_a_stop(tmp_path, monkeypatch):
    import xshells.deploy.run as run
    from xshells.deploy.case import material_from_spec
    from xshells.errors import STOP

    monkeypatch.setattr(STOP, "requested", False)

    def deploy_interrupted_inside_a_library(*args, **kwargs):
        try:
            STOP.request()
        except KeyboardInterrupt:
            raise RuntimeError("a C extension's own error") from None

    monkeypatch.setattr(run, "deploy", deploy_interrupted_inside_a_library)
    with pytest.raises(KeyboardInterrupt):
        run.run_deployment(str(EXAMPLES / "quad.obj"), material_from_spec(QUAD_MATERIAL), out_dir=str(tmp_path / "out"),
                           steps=3, progress=False)
    assert json.loads((tmp_path / "out" / "result.json").read_text())["status"] == "interrupted"


def test_stop_deferred_records_the_request_and_raises_at_the_next_check(monkeypatch):
    from xshells.errors import STOP

    monkeypatch.setattr(STOP, "requested", False)
    with STOP.deferred():
        STOP.request()  # no exception inside the region
        assert STOP.requested
    with pytest.raises(KeyboardInterrupt):
        STOP.check()
    with pytest.raises(KeyboardInterrupt):
        STOP.request()  # outside a region the request raises at once


def test_a_deploy_that_fails_with_an_error_leaves_stops_undeferred(tmp_path, monkeypatch):
    # The deferral of stops begins as the deploy ends; a deploy that raised a real error used to
    # leave it on, and every later stop in the same process (the app, a sweep worker) was only recorded.
    import xshells.deploy.run as run
    from xshells.deploy.case import material_from_spec
    from xshells.errors import STOP

    monkeypatch.setattr(STOP, "requested", False)

    def broken_deploy(*args, **kwargs):
        raise RuntimeError("a solver bug")

    monkeypatch.setattr(run, "deploy", broken_deploy)
    with pytest.raises(RuntimeError, match="a solver bug"):
        run.run_deployment(str(EXAMPLES / "quad.obj"), material_from_spec(QUAD_MATERIAL), out_dir=str(tmp_path / "out"),
                           steps=3, progress=False)
    assert STOP.deferring == 0
    with pytest.raises(KeyboardInterrupt):
        STOP.request()


def test_a_case_file_with_a_byte_order_mark_loads_and_a_folder_as_its_design_is_named(tmp_path):
    """Windows editors write a byte-order mark: it was "not valid JSON (Unexpected UTF-8 BOM)". And
    "file": "." (the case's own folder) was "unknown design file type ''"."""
    from xshells.deploy.case import load_case

    case = tmp_path / "bom.json"
    case.write_bytes(b"\xef\xbb\xbf" + json.dumps({"file": "d.obj", "angle_deg": 60}).encode())
    assert load_case(case).design_path == str(tmp_path / "d.obj")
    case.write_text(json.dumps({"file": ".", "angle_deg": 60}))
    with pytest.raises(InputError, match=r"bom\.json: key 'file' = \"\.\": a folder, not a design file"):
        load_case(case)
