"""No text from a diagram file reaches the generated module (security rule of DESIGN.md).

Guards the code-execution hole of issue #12: a ``name:`` holding ``\"\"\"`` followed by an
expression ran that expression during ``run``; block names with a trailing newline reached the
source. Hostile texts either get a clear DiagramError at load, or load and leave no trace in
the generated text, and nothing they contain ever runs.
"""
import hashlib
import os
import subprocess
import sys
import textwrap

import pytest

import spidersim
from spidersim.errors import SpidersimError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _payload(marker):
    return f"__import__('pathlib').Path({str(marker)!r}).write_text('ran')"


def _diagram(name="ok", block="a", desc="plain", instance_param="1"):
    return textwrap.dedent(f"""\
        name: {name}
        description: {desc}
        blocks:
          {block}: {{type: Constant, value: {instance_param}}}
          sink: {{type: Gain, k: 2}}
        connections:
          - {block}.y -> sink.u
        simulation: {{t_end: 0.01}}
        """)


# free texts the loader must accept (display name, description) and never put in the source
FREE_TEXTS = [
    '"\\"\\"\\" + {p} + \\"\\"\\""',
    "\"'''; {p}; '''\"",
    '"\\\\\\" {p} #"',
    '"x\\n{p}\\n"',
    '"ｎａｍｅ {p}"',           # fullwidth look-alikes
    '"nаme\\u200b {p}"',        # Cyrillic a, zero-width space
]


@pytest.mark.parametrize("text", FREE_TEXTS)
def test_free_text_never_reaches_the_source(tmp_path, text):
    marker = tmp_path / "marker"
    t = text.format(p=_payload(marker).replace('"', '\\"'))
    d = spidersim.loads(_diagram(name=t, desc=t))
    src = d.source(jit=False)
    assert "pathlib" not in src and "__import__" not in src and "write_text" not in src
    # the free text appears nowhere: neither the name nor any part of the payload
    assert "marker" not in src
    d.simulate(jit=False)
    assert not marker.exists()


HOSTILE_NAMES = [
    "'a\\n'",                       # trailing newline
    "'a\"\"\"'",
    "'__import__(\"os\")'",
    "'ａ'",                          # fullwidth a: isidentifier() but not ASCII
    "'bаd'",                         # Cyrillic a
    "'a\\u200b'",                    # zero-width space
    "'a b'",
    "'a\\\\b'",
]


@pytest.mark.parametrize("name", HOSTILE_NAMES)
def test_hostile_block_names_refused_at_load(name):
    text = _diagram(block=name).replace(f"- {name}.y", "- a.y")
    with pytest.raises(SpidersimError) as exc:
        spidersim.loads(text, file="hostile.yaml")
    assert exc.value.line is not None


def test_generated_text_only_identifiers_the_compiler_made():
    """Every identifier-like token of a block path is absent from the module text."""
    text = _diagram(block="zz_user_block_name").replace("sink", "qq_user_sink")
    d = spidersim.loads(text)
    src = d.source(jit=False)
    assert "zz_user_block_name" not in src and "qq_user_sink" not in src
    # and the names still reach the results through the system's tables
    r = d.simulate(jit=False)
    assert "zz_user_block_name.y" in r.names


SEED_DIAGRAMS = ["diagrams/algebraic_loop.yaml", "diagrams/force_control_rigid_ideal.yaml"]
_HASH = ("import hashlib, spidersim, sys\n"
         "for f in sys.argv[1:]:\n"
         "    d = spidersim.load(f)\n"
         "    print(hashlib.sha256(d.source().encode()).hexdigest())")


@pytest.fixture(scope="module")
def hashes_by_seed():
    """The generated text's hash of each of :data:`SEED_DIAGRAMS` under three hash seeds:
    one fresh interpreter per seed generates every diagram's text (the seed is fixed at
    interpreter start, so the diagrams can share it; one process per seed and diagram
    cost three imports of spidersim more). ``{diagram: [hash per seed]}``."""
    out = {f: [] for f in SEED_DIAGRAMS}
    for seed in ("1", "2", "12345"):
        env = dict(os.environ, PYTHONHASHSEED=seed)
        res = subprocess.run([sys.executable, "-c", _HASH,
                              *(os.path.join(ROOT, f) for f in SEED_DIAGRAMS)],
                             capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
        assert res.returncode == 0, res.stderr
        lines = res.stdout.split()
        assert len(lines) == len(SEED_DIAGRAMS), res.stdout
        for f, h in zip(SEED_DIAGRAMS, lines):
            out[f].append(h)
    return out


@pytest.mark.parametrize("diagram", SEED_DIAGRAMS)
def test_generated_text_independent_of_hash_seed(diagram, hashes_by_seed):
    """The cache key (the text) must not depend on set iteration order (issue #14 defect)."""
    out = hashes_by_seed[diagram]
    assert len(out) == 3 and all(len(h) == 64 for h in out), out
    assert len(set(out)) == 1, out
