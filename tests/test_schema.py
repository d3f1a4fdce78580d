"""The JSON Schema for editors (issue #16 item 2): generated from the block registry, the
repository copy is up to date, every shipped diagram validates, malformed ones do not."""
import glob
import json
import os

import jsonschema
import pytest
import yaml

from spidersim.cli import main
from spidersim.schema import dumps, schema

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COPY = os.path.join(ROOT, "schema", "spidersim.schema.json")
SHIPPED = sorted(glob.glob(os.path.join(ROOT, "diagrams", "**", "*.yaml"), recursive=True)
                 + [os.path.join(ROOT, "spider.yaml")])
VALIDATOR = jsonschema.Draft202012Validator(schema())


def test_schema_is_valid_draft_2020_12():
    jsonschema.Draft202012Validator.check_schema(schema())
    assert schema()["$schema"].endswith("2020-12/schema")


def test_repository_copy_is_up_to_date():
    with open(COPY, encoding="utf-8") as fh:
        assert fh.read() == dumps(), "run: spidersim schema -o schema/spidersim.schema.json"


def test_cli_writes_it(tmp_path, capsys):
    assert main(["schema", "-o", str(tmp_path / "s.json")]) == 0
    assert json.loads((tmp_path / "s.json").read_text()) == schema()


@pytest.mark.parametrize("path", SHIPPED, ids=[os.path.relpath(p, ROOT) for p in SHIPPED])
def test_shipped_diagram_validates_and_points_to_the_schema(path):
    with open(path, encoding="utf-8") as fh:
        first = fh.readline()
        data = yaml.safe_load(fh)
    errors = [f"{list(e.path)}: {e.message}" for e in VALIDATOR.iter_errors(data)]
    assert not errors, errors
    ref = first.split("$schema=")[1].strip()
    assert first.startswith("# yaml-language-server:")
    assert os.path.samefile(os.path.join(os.path.dirname(path), ref), COPY)


SERVO = {"blocks": {"c": {"type": "Constant", "value": 1}, "g": {"type": "Gain", "k": 2}},
         "connections": ["c.y -> g.u"]}


def _with(path, value):
    import copy
    d = copy.deepcopy(SERVO)
    node = d
    for k in path[:-1]:
        node = node.setdefault(k, {})
    node[path[-1]] = value
    return d


MALFORMED = [
    ({"connections": ["a.y -> b.u"]}, "no blocks section"),
    (_with(["blokcs"], {}), "unknown section"),
    (_with(["blocks", "g", "kk"], 2), "unknown parameter of a library block"),
    (_with(["blocks", "g", "k"], True), "boolean for a real parameter"),
    (_with(["blocks", "s"], {"type": "Sum", "signs": 3}), "number for a string parameter"),
    (_with(["blocks", "h"], {"k": 2}), "block without a type"),
    (_with(["blocks", "a b"], {"type": "Gain"}), "block name with a space"),
    (_with(["connections"], ["c.y => g.u"]), "connection arrow"),
    (_with(["connections"], ["c.y[::2] -> g.u"]), "element range with a step"),
    (_with(["connections"], ["c.y[] -> g.u"]), "empty brackets"),
    (_with(["simulation"], {"t_end": 1, "method": "euler"}), "unknown method"),
    (_with(["simulation"], {"tend": 1}), "unknown simulation key"),
    (_with(["plots"], [{"signals": [], "title": "x"}]), "plot without signals"),
    (_with(["plots"], [{"signals": ["g.y"], "file": "../x.png"}]), "plot file with a folder"),
    (_with(["plots"], [{"signals": ["g.y"], "colour": "red"}]), "unknown plot key"),
    (_with(["log"], "everything"), "log neither all nor a list"),
    (_with(["metrics"], {"m": {"signal": "g.y", "reduce": "median"}}), "unknown reducer"),
    (_with(["blocks", "w"], {"type": "WrenchSensor", "frame": "tool"}), "choice not allowed"),
    (_with(["plots"], [{"signals": ["g.y"], "file": "volts.txt"}]), "plot file extension"),
    (_with(["plots"], [{"signals": ["g.y"], "file": "volts"}]), "plot file without extension"),
    (_with(["plots"], [{"signals": ["g.y"], "file": "volts.gif"}]), "gif for a line plot"),
    (_with(["plots"], [{"signals": ["g.y"], "kind": "animation", "file": "arm.png"}]),
     "png for an animation"),
    (_with(["plots"], [{"signals": ["g.y"], "file": "v" * 118 + ".png"}]), "name too long"),
]


@pytest.mark.parametrize("data,why", MALFORMED, ids=[m[1] for m in MALFORMED])
def test_malformed_diagram_fails(data, why):
    assert VALIDATOR.is_valid(SERVO)                    # the base is valid...
    assert not VALIDATOR.is_valid(data), why            # ...the change is not


def test_subsystem_types_are_not_constrained():
    """A type that is not a library block is a subsystem type: its parameters are free."""
    d = _with(["blocks", "j1"], {"type": "joint", "q0": 0.3, "anything": [1, 2]})
    assert VALIDATOR.is_valid(d)


ACCEPTED_BY_BOTH = [
    (_with(["name"], 2024), "number as the name"),
    (_with(["description"], 7), "number as the description"),
    (_with(["plots"], [{"signals": ["g.y"], "title": 5}]), "number as a plot title"),
    (_with(["metrics"], {"m": {"signal": "g.y", "reduce": "max", "unit": 1}}),
     "number as a metric unit"),
    (_with(["plots"], [{"signals": ["g.y"], "file": "Volts.PNG"}]), "upper-case extension"),
    (_with(["plots"], [{"signals": ["g.y"], "file": "v" * 117 + ".png"}]), "longest name"),
    (_with(["connections"], ["c.y[:] -> g.u"]), "range with both bounds left out"),
    (_with(["connections"], ["c.y[-1:] -> g.u"]), "range to the end"),
    (_with(["connections"], ["c.y[ : 1] -> g.u"]), "range from the start"),
]


@pytest.mark.parametrize("data,why", ACCEPTED_BY_BOTH, ids=[m[1] for m in ACCEPTED_BY_BOTH])
def test_schema_accepts_what_the_loader_accepts(data, why, tmp_path, capsys):
    """An editor must not flag a valid diagram: a number where the loader takes a text
    ("a number is taken as its text") passes both (a hostile-input review found the schema
    refusing them)."""
    path = tmp_path / "d.yaml"
    path.write_text(yaml.safe_dump(data))
    assert VALIDATOR.is_valid(data), why
    assert main(["check", str(path)]) == 0, capsys.readouterr().err
