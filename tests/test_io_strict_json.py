"""User-written JSON: a key given twice is named, not silently resolved to its last value."""
import pytest

from data_paths import EXAMPLES
from xshells.errors import InputError
from xshells.io.strict_json import loads


def test_a_repeated_key_is_named_at_any_depth():
    assert loads('{"a": 1, "b": {"a": 2}}', "f.json") == {"a": 1, "b": {"a": 2}}  # the same key in two objects
    for text in ('{"steps": 3, "steps": 4}', '{"material": {"E": 1, "E": 2}}'):
        with pytest.raises(InputError) as err:
            loads(text, "f.json")
        assert str(err.value).startswith("f.json: key ") and "given twice" in str(err.value)


def test_invalid_json_names_the_line():
    with pytest.raises(InputError, match=r"^f.json:2: not valid JSON"):
        loads('{"a": 1,\n}', "f.json")
    with pytest.raises(InputError, match=r"^f.json: not valid JSON \(nested too deeply\)"):  # a RecursionError
        loads("[" * 100000 + "]" * 100000, "f.json")


def test_case_files_and_sweep_files_refuse_a_repeated_key(tmp_path):
    from xshells.deploy.case import load_case
    from xshells.sweeps.spec import load_spec

    case = tmp_path / "case.json"
    case.write_text(f'{{"file": "{EXAMPLES / "quad.obj"}", "steps": 3, "steps": 4}}')
    with pytest.raises(InputError, match=r"case.json: key 'steps' is given twice"):
        load_case(case)
    sweep = tmp_path / "s.yaml"
    sweep.write_text(f"task: deploy\nbase:\n  file: {EXAMPLES / 'quad.obj'}\n  steps: 3\n  steps: 4\naxes:\n  angle_deg: [100]\n")
    with pytest.raises(InputError, match=r"s.yaml:5: .*key 'steps' is given twice"):
        load_spec(sweep)


def test_an_integer_beyond_pythons_conversion_limit_and_a_binary_sweep_file_are_input_errors(tmp_path):
    """Both were internal errors (exit 3): Python refuses to convert an integer of more than 4300 digits,
    and a sweep file in UTF-16 failed to decode."""
    from xshells.sweeps.spec import load_spec

    with pytest.raises(InputError, match=r"^f.json: not valid JSON \(Exceeds the limit"):
        loads('{"steps": ' + "9" * 5000 + "}", "f.json")
    big = tmp_path / "big.yaml"
    big.write_text("task: deploy\nbase:\n  steps: " + "9" * 5000 + "\n")
    with pytest.raises(InputError, match=r"big.yaml: not valid YAML \(Exceeds the limit"):
        load_spec(big)
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(InputError, match=r"bin.yaml: not a text file"):
        load_spec(binary)
