"""The published JSON Schema of sweep specs (``docs/sweep.schema.json``), generated from the checks that run.

A spec's ``base`` and ``cases`` entries take the case files' keys (their
schema: :mod:`xshells.io.case_schema`), the material's keys as dotted paths
or short aliases, ``direction`` (every task) and ``start`` (the deploy task only), and the
chosen task's own parameters (each registered with a pydantic-backed check
that carries its JSON Schema); ``axes`` maps the same keys to lists of
values. Regenerate with::

    python -m xshells.sweeps.schema docs/sweep.schema.json
"""
from __future__ import annotations

import json
import sys

from ..io.case_schema import json_schema as case_json_schema
from . import tasks as T
from .spec import ALIASES, CASE_CHECKS, CASE_KEYS, DEPLOY_ONLY

def _case_key_schemas() -> dict:
    case = case_json_schema()
    material = case["$defs"]["MaterialSpec"]["properties"]
    out = {}
    for key in CASE_KEYS:
        prop = material[key.split(".", 1)[1]] if key.startswith("material.") else case["properties"][key]
        out[key] = {k: v for k, v in prop.items() if k not in ("title", "default")}
    for key in ("direction", "start"):
        only = " (deploy task only)" if key in DEPLOY_ONLY else ""
        out[key] = dict(CASE_CHECKS[key].json_schema, description=f"xshells deploy --{key}{only}")
    out["material"] = {"$ref": "#/$defs/MaterialSpec", "description": "the material as an object, as in a case file"}
    for alias, target in ALIASES.items():
        if target in out:
            out[alias] = dict(out[target], description=f"short for {target}")
    return out


def json_schema() -> dict:
    """The sweep spec's JSON Schema: one ``base``/``cases`` key set per task (``task`` chooses it)."""
    case = case_json_schema()
    keys = _case_key_schemas()
    variants = []
    for name in sorted(T.BUILTIN_TASKS):
        task = T.REGISTRY[name]
        props = {k: v for k, v in keys.items() if name == "deploy" or k not in DEPLOY_ONLY} if task.case else {}
        props.update({k: dict(getattr(check, "json_schema", {}), description=f"{name} task parameter")
                      for k, check in task.params.items()})
        entry = {"type": "object", "properties": props, "additionalProperties": False}
        axes = {"type": "object", "properties": {k: {"type": "array", "minItems": 1, "items": v} for k, v in props.items()},
                "additionalProperties": False}
        task_prop = {"const": name} if name != "deploy" else {"enum": ["deploy"]}
        variants.append({
            "if": {"required": ["task"], "properties": {"task": {"const": name}}} if name != "deploy" else
                  {"anyOf": [{"not": {"required": ["task"]}}, {"properties": {"task": {"const": "deploy"}}}]},
            "then": {"properties": {"task": task_prop, "base": entry, "cases": {"type": "array", "minItems": 1, "items": entry},
                                    "axes": axes}},
        })
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "xshells sweep spec",
        "description": "A design-space sweep (xshells sweep): a task, a base case, axes of values and optional cases; "
                       "see docs/sweeps.md. Units follow the design files.",
        "type": "object",
        "properties": {"name": {"type": "string", "minLength": 1}, "task": {"enum": sorted(T.BUILTIN_TASKS)},
                       "base": {"type": "object"}, "axes": {"type": "object"}, "cases": {"type": "array"}},
        "additionalProperties": False,
        "allOf": variants,
        "$defs": {"MaterialSpec": case["$defs"]["MaterialSpec"]},
    }


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m xshells.sweeps.schema SCHEMA.json", file=sys.stderr)
        return 2
    from ..io.export import atomic_write_text

    atomic_write_text(argv[0], json.dumps(json_schema(), indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
