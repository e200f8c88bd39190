"""The case file's schema: every key, its type, its range and its unit, in one declarative place.

A case file is a JSON object (as an entry of the paper's ``cases.json``).
:func:`validate_case` checks a parsed object against :class:`CaseFile` and
turns the first problem into one line naming the file and the key; unknown
keys are refused with the nearest known name. The same models give the
published JSON Schema (``docs/case.schema.json``) and its page
(``docs/case.md``)::

    python -m xshells.io.case_schema docs/case.schema.json docs/case.md

pydantic (not jsonschema) because one model both validates with typed,
strict fields (no "60" for 60, no 5 for a path) and *generates* the JSON
Schema that editors and Grasshopper users validate against, so the two can
never drift apart; jsonschema would need the schema written by hand and the
parsing done a second time.

Units follow the design file (the bundled data: millimetres; E in MPa).
"""
from __future__ import annotations

import difflib
import json
import math
import sys
from typing import Literal, Optional, Union

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from ..errors import InputError



class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class MaterialSpec(_Strict):
    """The beams' cross-section and elastic constants."""

    type: str = Field("rectangle", description="cross-section type: rectangle, ellipse, I, L, + (case-insensitive; "
                                                "also rect, ibeam, plus) or contour, which reads contour_file")
    E: Optional[float] = Field(None, gt=0, allow_inf_nan=False,
                               description="Young's modulus, in the design's stress unit (MPa for millimetres); default 20000, or the section file's")
    nu: Optional[float] = Field(None, gt=-1, lt=0.5, allow_inf_nan=False,
                                description="Poisson's ratio (dimensionless); default 0.3, or the section file's")
    params: list[float] = Field(default_factory=list, max_length=16,
                                description="the type's dimensions in the design's length unit: rectangle width, height "
                                            "(default 10, 7); "
                                            "ellipse a, b; I w1, w2, w3, h1, h2, h3; L and + a, b, t1, t2")
    contour_file: Optional[str] = Field(None, min_length=1,
                                        description="for type 'contour': a cross-section file (.obj, .msh or .json), relative to the case file")
    stiff_axis: Optional[Literal["D1", "D2"]] = Field(
        None, description="which material director the larger bending stiffness is about")
    grade: Optional[str] = Field(None, min_length=1, description="a named material (E, ν, density, strength; "
                                 "docs/analysis.md): gfrp-e23, softwood-c24, aluminium-6063-t6, birch-plywood; "
                                 "keys given here override its values")
    density: Optional[float] = Field(None, gt=0, allow_inf_nan=False,
                                     description="mass per volume, in the design's units (t/mm³ for millimetres: 1.9e-9 is 1900 kg/m³)")
    strength: Optional[float] = Field(None, gt=0, allow_inf_nan=False,
                                      description="allowable stress for the utilization, in the stress unit (MPa for millimetres)")

    @model_validator(mode="after")
    def _consistent(self):
        from ..section.profiles import TYPE_ALIASES

        if self.grade is not None:
            from ..analysis.materials import named_material

            named_material(self.grade)  # one line naming the known grades

        kind = self.type.strip().lower()
        if kind not in set(TYPE_ALIASES) | {"contour"}:
            known = ", ".join(sorted(set(TYPE_ALIASES.values()), key=str.lower))
            raise ValueError(f"unknown cross-section type {self.type!r} (known: {known}, contour)")
        if kind == "contour" and not self.contour_file:
            raise ValueError("type 'contour' needs contour_file")
        if kind != "contour" and self.contour_file:
            raise ValueError(f"contour_file is only read with type 'contour' (type is {self.type!r})")
        if kind != "contour" and not self.params and TYPE_ALIASES[kind] != "rectangle":
            raise ValueError(f"type {self.type!r} needs its dimensions in 'params' (only a rectangle defaults to 10 × 7)")
        if any(not (math.isfinite(v) and v > 0) for v in self.params):
            raise ValueError(f"params must be positive finite lengths, got {self.params}")
        if kind != "contour" and self.params:
            # checked here, so that the line names the case file and its key: the section's own check, when
            # the material was built, said only "rectangle: rectangle takes 2 parameters (width, height), got 1"
            from ..section.profiles import PARAM_NAMES

            names = PARAM_NAMES[TYPE_ALIASES[kind]]
            if len(self.params) != len(names.split(", ")):
                raise ValueError(f"{TYPE_ALIASES[kind]} takes {len(names.split(', '))} parameters ({names}), got "
                                 f"{len(self.params)}")
        return self


class CaseFile(_Strict):
    """An X-shell case: a design, its material, and how far to deploy it."""

    file: str = Field(..., min_length=1, description="the design: a line-graph .obj or a gmsh .msh, relative to the case file")
    flat_file: Optional[str] = Field(None, min_length=1, description="a flat assembly state to read instead of file")
    name: Optional[str] = Field(None, description="a name for outputs (default: the case file's name)")
    material: Optional[MaterialSpec] = Field(None, description="default: rectangle 10 × 7, E 20000, ν 0.3")
    subdivision: int = Field(10, ge=3, le=1000, description="edges per rod segment (at least 3)")
    steps: int = Field(40, ge=1, le=100000, description="deployment increments")
    angle_deg: Optional[float] = Field(None, gt=0, lt=180, allow_inf_nan=False,
                                       description="target average opening angle of the deployed state, degrees")
    angle_rad: Optional[float] = Field(None, gt=0, lt=math.pi, allow_inf_nan=False,
                                       description="the same in radians")
    open_by_deg: Optional[float] = Field(None, gt=0, lt=180, allow_inf_nan=False,
                                         description="open by this much from the assembly state, degrees (default 60 when no angle is given)")
    rest_lengths: Optional[str] = Field(None, min_length=1,
                                        description="a file of per-segment rest lengths (design parameters) that replaces the rest-length solve")
    direction: Optional[Literal["up", "down"]] = Field(
        None, description="which way the flat state buckles: up (default) = its middle rises along the layout normal")
    guide: Optional[str] = Field(
        None, min_length=1,
        description="a file of deployed joint positions, one 'x y z' line per joint: at the target angle the shell is held "
                    "on them and let go, to settle into that equilibrium where the design has more than one")
    # informational keys of the paper's cases.json, kept so that its entries load as they are
    figure: Optional[str] = Field(None, description="informational: the paper's figure")
    description: Optional[str] = Field(None, description="informational: free text")
    note: Optional[str] = Field(None, description="informational: free text")
    angle_deg_note: Optional[str] = Field(None, description="informational: where the angle comes from")
    reference_sparse_torques: Optional[Union[str, list[str]]] = Field(
        None, description="informational: the reference's torque file(s)")

    @model_validator(mode="after")
    def _one_angle(self):
        given = [k for k in ("angle_deg", "angle_rad", "open_by_deg") if getattr(self, k) is not None]
        if len(given) > 1:
            raise ValueError(f"give one of angle_deg, angle_rad, open_by_deg, not {' and '.join(given)}")
        return self


def _known_keys(model) -> list[str]:
    return list(model.model_fields)


def _where(loc) -> str:
    return ".".join(str(p) for p in loc) if loc else ""


def _one_line(path, exc: ValidationError, data) -> str:
    err = exc.errors()[0]
    loc = err.get("loc", ())
    key = _where(loc)
    if err["type"] == "extra_forbidden":
        model = MaterialSpec if len(loc) > 1 and loc[0] == "material" else CaseFile
        close = difflib.get_close_matches(str(loc[-1]), _known_keys(model), n=1, cutoff=0.6)
        hint = f" (did you mean '{close[0]}'?)" if close else f" (known: {', '.join(_known_keys(model))})"
        return f"{path}: unknown key '{key}'{hint}"
    if err["type"] == "missing":
        return f"{path}: missing key '{key}'"
    msg = err["msg"]
    for prefix in ("Value error, ", "Assertion failed, "):
        if msg.startswith(prefix):
            msg = msg[len(prefix):]
    if not key:
        return f"{path}: {msg}"
    value = err.get("input")
    if isinstance(value, (str, int, float, bool, type(None))):
        return f"{path}: key '{key}' = {json.dumps(value)}: {msg}"
    return f"{path}: key '{key}': {msg}"


def validate_case(data, path="<case>") -> CaseFile:
    """Check a parsed case object; InputError with one line naming ``path`` and the key."""
    if not isinstance(data, dict):
        raise InputError(f"{path}: a case is a JSON object with at least a 'file' key, got {type(data).__name__}")
    try:
        return CaseFile.model_validate(data)
    except ValidationError as exc:
        raise InputError(_one_line(path, exc, data)) from None


def field_check(name: str):
    """A check of one case key's value (``"angle_deg"``, ``"material.E"``): returns the value or raises ValueError.

    Sweep specs check their ``base``, ``cases`` and ``axes`` values with these, so that a sweep
    and a case file accept exactly the same values.
    """
    from typing import Annotated

    from pydantic import TypeAdapter

    model, key = (MaterialSpec, name.split(".", 1)[1]) if name.startswith("material.") else (CaseFile, name)
    info = model.model_fields[key]
    adapter = TypeAdapter(Annotated[info.annotation, info])

    def check(value):
        try:
            return adapter.validate_python(value, strict=True)
        except ValidationError as exc:  # with the value, as a case file's error and a sweep task parameter's give it
            raise ValueError(f"{exc.errors()[0]['msg'].removeprefix('Value error, ')}, got {value!r}") from None

    return check


ANGLE_KEYS = ("angle_deg", "angle_rad", "open_by_deg")


def _given(key: str) -> dict:
    """JSON Schema: ``key`` is present and not null (pydantic reads null as not given)."""
    return {"required": [key], "properties": {key: {"not": {"type": "null"}}}}


def _words(words) -> str:
    """An ECMA-262 pattern matching any of ``words`` case-insensitively, with surrounding blanks (as ``strip().lower()``)."""
    def one(w):
        return "".join(f"[{c.lower()}{c.upper()}]" if c.isalpha() else ("\\" + c if c in "+." else c) for c in w)
    return "^\\s*(" + "|".join(one(w) for w in sorted(words)) + ")\\s*$"


def _cross_key_rules(schema: dict) -> None:
    """The validators' rules across keys, in JSON Schema, so that the published schema refuses what
    :func:`validate_case` refuses (tested against each other): one angle key at most; a known
    cross-section type and grade; contour_file exactly with type contour; dimensions for every type
    but the rectangle, as many as the type takes; positive lengths."""
    from itertools import combinations

    from ..analysis.materials import LIBRARY
    from ..section.profiles import PARAM_NAMES, TYPE_ALIASES

    schema["not"] = {"anyOf": [{"allOf": [_given(a), _given(b)]} for a, b in combinations(ANGLE_KEYS, 2)]}
    mat = schema["$defs"]["MaterialSpec"]
    props = mat["properties"]
    props["type"]["pattern"] = _words(list(TYPE_ALIASES) + ["contour"])
    props["grade"]["anyOf"][0]["pattern"] = _words(LIBRARY)
    props["params"]["items"]["exclusiveMinimum"] = 0
    is_type = lambda words: {"properties": {"type": {"pattern": _words(words)}}}  # noqa: E731
    sized = [k for k, v in TYPE_ALIASES.items() if v != "rectangle"]
    mat["allOf"] = [
        # type defaults to rectangle, so only a given type can be contour
        {"if": {"required": ["type"], **is_type(["contour"])}, "then": _given("contour_file"),
         "else": {"not": _given("contour_file")}},
        {"if": {"required": ["type"], **is_type(sized)},
         "then": {"required": ["params"], "properties": {"params": {"minItems": 1}}}},
    ]
    # each type's count of dimensions, where any are given (an absent type is a rectangle: the pattern of an
    # absent key holds, so only the other types' rules need "required")
    for kind, names in PARAM_NAMES.items():
        n = len(names.split(", "))
        given = {} if kind == "rectangle" else {"required": ["type"]}
        mat["allOf"].append({"if": {**given, **is_type([k for k, v in TYPE_ALIASES.items() if v == kind])},
                             "then": {"properties": {"params": {"anyOf": [{"maxItems": 0},
                                                                          {"minItems": n, "maxItems": n}]}}}})


def json_schema() -> dict:
    """The published JSON Schema of a case file."""
    schema = CaseFile.model_json_schema()
    _cross_key_rules(schema)
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "xshells case file"
    schema["description"] = ("An X-shell case: a design, its material and how far to deploy it. Units follow the "
                             "design file (the bundled data: millimetres, E in MPa). Paths are relative to the case file.")
    return schema


def _type_text(prop: dict, defs: dict) -> str:
    if "$ref" in prop:
        return "object (" + prop["$ref"].rsplit("/", 1)[-1] + ")"
    if "anyOf" in prop:
        kinds = [_type_text(p, defs) for p in prop["anyOf"] if p.get("type") != "null"]
        return " or ".join(kinds)
    if "enum" in prop:
        return "one of " + ", ".join(f"`{v}`" for v in prop["enum"])
    if "const" in prop:
        return f"`{prop['const']}`"
    t = prop.get("type", "")
    if t == "array":
        return f"list of {_type_text(prop.get('items', {}), defs)}"
    return t


def _range_text(prop: dict) -> str:
    p = prop
    if "anyOf" in prop:
        p = next((q for q in prop["anyOf"] if q.get("type") != "null"), prop)
    parts = []
    for key, sym in (("exclusiveMinimum", ">"), ("minimum", "≥"), ("exclusiveMaximum", "<"), ("maximum", "≤")):
        if key in p:
            parts.append(f"{sym} {p[key]:g}" if isinstance(p[key], (int, float)) else f"{sym} {p[key]}")
    return ", ".join(parts)


def markdown() -> str:
    """``docs/case.md``, generated from :func:`json_schema`."""
    schema = json_schema()
    defs = schema.get("$defs", {})
    out = ["# Case files", "",
           "<!-- generated by `python -m xshells.io.case_schema docs/case.schema.json docs/case.md`: do not edit -->", "",
           schema["description"], "",
           "A case file is a JSON object. Every command (`xshells deploy`, `optimize`, `sparsify`, `app`) reads it "
           "through one schema, published as [`case.schema.json`](case.schema.json) (JSON Schema 2020-12) for "
           "editors and Grasshopper. Unknown keys are refused with the nearest known name.", "",
           "```json",
           json.dumps({"name": "asymm_wings_pointy", "file": "flat_opt.msh", "rest_lengths": "design_parameters.txt",
                       "material": {"type": "rectangle", "E": 20000, "nu": 0.3, "params": [12, 8], "stiff_axis": "D1"},
                       "angle_rad": 2.0, "steps": 50, "subdivision": 10}, indent=1),
           "```", ""]

    def table(title, obj):
        out.extend([f"## {title}", "", "| key | type | range | default | meaning |", "|---|---|---|---|---|"])
        required = set(obj.get("required", []))
        for key, prop in obj["properties"].items():
            default = "required" if key in required else (
                json.dumps(prop["default"]) if prop.get("default") not in (None, []) else "")
            out.append(f"| `{key}` | {_type_text(prop, defs)} | {_range_text(prop)} | {default} | "
                       f"{prop.get('description', '')} |")
        out.append("")

    table("Keys", schema)
    table("`material`", defs["MaterialSpec"])
    out.append("One of `angle_deg`, `angle_rad` and `open_by_deg` at most. In `material`: `contour_file` "
               "with type `contour` and only then; `params` for every type but the rectangle (which defaults "
               "to 10 × 7); types and grades are case-insensitive. The published schema states these rules "
               "too (`not`, `allOf` with `if`/`then`, case-insensitive patterns).")
    out.extend(["", "## `guide`", "",
                "A design can have more than one stable equilibrium at its deployed angle, and the deployment from "
                "flat reaches one of them (the `direction` chooses between mirror images only). A `guide` names "
                "another: a text file with one `x y z` line per joint, in the design's joint order and units, in "
                "any rigid placement (`#` starts a comment). Once the deployment reaches its angle, springs on the "
                "joints pull the shell onto the guide, their stiffness raised in steps until it is within 5 % of a "
                "segment of it; then the springs are taken away at once and the shell is solved to equilibrium at "
                "the same angle, with no load. In the workshop: open the shell, push it into shape, let go.", "",
                "What is reported is the equilibrium it settles into, with its own stability check: the guide "
                "carries no force in the result, and a guide that is no equilibrium is left (the shell settles "
                "where its beams take it). `result.json`'s `guide` says how far the state let go lies from the "
                "guide (`released_rms`, relative to the span) and from where the deployment from flat ended "
                "(`moved`, largest joint), and both energies. Where the springs cannot bring the shell close to "
                "the guide, the state the deployment reached is kept, with a warning. `xshells inverse` writes a "
                "guide (`deploy_guide.txt`) where its design's deployment from flat reaches another equilibrium "
                "than the one it fitted (docs/inverse.md, \"Guided deployments\"); where its input case names a "
                "guide, `xshells optimize` writes its optimized state as the guide of the case it writes; the app follows a case's guide while the "
                "layout keeps its joints. `xshells deploy --guide FILE` gives one on the command line."])
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print("usage: python -m xshells.io.case_schema SCHEMA.json PAGE.md", file=sys.stderr)
        return 2
    from .export import atomic_write_text

    atomic_write_text(argv[0], json.dumps(json_schema(), indent=2) + "\n")
    atomic_write_text(argv[1], markdown())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
