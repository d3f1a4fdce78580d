"""Mapping keys of a diagram are names: the loader (spidersim.text.yamlio) refuses the keys
YAML reads as numbers, booleans or null, at their line, so that no later check meets a
key that is not a text (difflib's suggestions raised TypeError on an int key)."""
import re

import pytest

from spidersim.errors import DiagramError
from spidersim.text.yamlio import load_text


@pytest.mark.parametrize("key, words", [
    ("5", "mapping key '5' is an integer"), ("1.5", "mapping key '1.5' is a number"),
    ("on", "mapping key 'on' is a boolean"), ("~", "mapping key '~' is empty (null)"),
])
def test_keys_that_yaml_reads_as_no_text_are_refused(key, words):
    """``5:``, ``1.5:``, ``on:`` (YAML 1.1 boolean) and ``~:`` as a key: a DiagramError at
    the key's line saying what YAML read and how to quote it."""
    with pytest.raises(DiagramError, match=re.escape(words)) as ei:
        load_text(f"blocks:\n  c:\n    {key}: 1\n", "d.yaml")
    assert ei.value.line == 3 and "quote it" in ei.value.message


def test_quoted_keys_and_names_load():
    """Quoted, the same keys are texts and load (the refusal is about types, not
    spelling)."""
    data = load_text("a: {'5': 1, 'on': 2, '1.5': 3}\n", "d.yaml")
    assert list(data["a"]) == ["5", "on", "1.5"]
