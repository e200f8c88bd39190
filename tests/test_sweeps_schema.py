"""The published JSON Schema of sweep specs (xshells.sweeps.schema)."""
import json

import jsonschema
import pytest
import yaml

from xshells.sweeps.schema import json_schema
from xshells.sweeps.spec import _yaml_loader

from data_paths import EXAMPLES, REPO


def test_the_published_sweep_schema_is_generated_and_validates_the_examples():
    schema = json_schema()
    assert json.loads((REPO / "docs" / "sweep.schema.json").read_text()) == schema, \
        "regenerate: python -m xshells.sweeps.schema docs/sweep.schema.json"
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(yaml.load((EXAMPLES / "sweep_example.yaml").read_text(), Loader=_yaml_loader()), schema)
    text = (REPO / "docs" / "sweeps.md").read_text()
    specs = [yaml.load(b.split("```", 1)[0], Loader=_yaml_loader()) for b in text.split("```yaml")[1:]]
    specs = [s for s in specs if isinstance(s, dict) and "base" in s]
    assert specs
    for s in specs:
        jsonschema.validate(s, schema)
    for bad in ({"base": {"file": "a", "angel_deg": 3}}, {"task": "sparsify", "base": {"file": "a", "gamma": 1}},
                {"base": {"file": "a"}, "axes": {"angle_deg": [200]}}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, schema)
