"""Arm data files (``Chain.from_yaml``) are data from users, checked like diagrams: every
malformed file gets a specific error with the file and line, never a traceback or a chain
that only fails (or silently misbehaves) during a run."""
import textwrap

import numpy as np
import pytest

from spidersim.errors import DiagramError
from spidersim.multibody import Chain

GOOD = """\
name: two_links
links:
  - {d: 0.3, a: 0, alpha: pi/2, mass: 4, com: [0, 0, 0.15], inertia: [0.05, 0.05, 0.01]}
  - {d: 0, a: 0.5, alpha: 0, mass: 2, com: [0.25, 0, 0.3], inertia: [0.002, 0.05, 0.05]}
"""

LINK1 = "  - {d: 0.3, a: 0, alpha: pi/2, mass: 4, com: [0, 0, 0.15], inertia: [0.05, 0.05, 0.01]}"


def _write(tmp_path, text):
    p = tmp_path / "arm.yaml"
    p.write_text(textwrap.dedent(text))
    return str(p)


def test_good_file_loads(tmp_path):
    """The reference shape of a file: two links, expressions allowed (pi/2)."""
    ch = Chain.from_yaml(_write(tmp_path, GOOD))
    assert ch.n == 2 and ch.name == "two_links"
    assert np.linalg.eigvalsh(ch.mass_matrix([0.3, -0.2])).min() > 0


@pytest.mark.parametrize("text, line, words", [
    ("- 1\n- 2\n", None, ["a mapping with 'links'"]),
    ("links: []\n", None, ["non-empty 'links'"]),
    ("links: [" + ", ".join(["{d: 0, a: 0, alpha: 0, mass: 1, com: [0,0,0], "
                             "inertia: [1,1,1]}"] * 65) + "]\n", None, ["65 entries", "64"]),
    ("name: x\nlinkz: []\n", 2, ["unknown key(s) linkz"]),
    ("links:\n  - 3\n", 2, ["links[0] must be a mapping"]),
    ("links:\n  - {d: 0, a: 0, alpha: 0, mass: 1, com: [0, 0, 0]}\n", 2, ["lacks 'inertia'"]),
    ("links:\n  - {d: 0, a: 0, alpha: 0, mass: 1, com: [0, 0, 0], inertia: [1, 1, 1], "
     "colour: red}\n", 2, ["unknown key(s) colour"]),
    (LINK1.replace("mass: 4", "mass: true").join(["links:\n", "\n"]), 2,
     ["links[0].mass", "true/false"]),
    (LINK1.replace("mass: 4", "mass: -4").join(["links:\n", "\n"]), 2, ["mass >= 0"]),
    (LINK1.replace("d: 0.3", "d: .inf").join(["links:\n", "\n"]), 2, ["finite"]),
    (LINK1.replace("d: 0.3", "d: __import__('os')").join(["links:\n", "\n"]), 2,
     ["links[0].d", "expected a number"]),
    (LINK1.replace("com: [0, 0, 0.15]", "com: [0, 0.15]").join(["links:\n", "\n"]), 2,
     ["links[0].com", "3 numbers"]),
    (LINK1.replace("[0.05, 0.05, 0.01]", "[0.05, 0.01]").join(["links:\n", "\n"]), 2,
     ["links[0].inertia", "3 principal moments"]),
    (LINK1.replace("[0.05, 0.05, 0.01]", "[0.05, 0.01, 0.1]").join(["links:\n", "\n"]), 2,
     ["not a rigid body's"]),
    (LINK1.replace("[0.05, 0.05, 0.01]", "[0.05, -0.05, 0.01]").join(["links:\n", "\n"]), 2,
     ["not a rigid body's"]),
    (LINK1.replace("[0.05, 0.05, 0.01]", "[[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]")
     .join(["links:\n", "\n"]), 2, ["not symmetric"]),
    (LINK1.replace("[0.05, 0.05, 0.01]", "[[1, 0, 0], [0, 1, 0]]").join(["links:\n", "\n"]),
     2, ["3 principal moments or a 3 x 3"]),
    (LINK1.join(["links:\n", "\n"]) + "gravity: [0, -9.81]\n", 3, ["gravity", "3 numbers"]),
    ("links:\n  - {d: 0, a: 0, alpha: 0, mass: 0, com: [0, 0, 0], inertia: [0, 0, 0]}\n",
     None, ["singular", "moves no inertia"]),
])
def test_malformed_arm_files_are_refused_with_file_and_line(tmp_path, text, line, words):
    """Each malformed data file: a DiagramError naming the file (and the entry's line
    where there is one) and saying what was expected and what was found."""
    path = _write(tmp_path, text)
    with pytest.raises(DiagramError) as ei:
        Chain.from_yaml(path)
    msg = str(ei.value)
    assert msg.startswith(path + (f":{line}:" if line else ":")), msg
    for w in words:
        assert w in msg, msg


def test_missing_file_and_the_diagram_error_through_the_arm_block(tmp_path):
    """An Arm naming a missing or malformed data file fails when the diagram is loaded,
    naming the block, the parameter and the data file's own error."""
    import spidersim
    bad = _write(tmp_path, "links:\n  - {d: 0, a: 0, alpha: 0, mass: 1, com: [0, 0], "
                           "inertia: [1, 1, 1]}\n")
    for model, words in ((str(tmp_path / "none.yaml"), ["not found"]),
                         (bad, ["links[0].com", "3 numbers"])):
        text = ("blocks:\n  tau: {type: Constant, value: [0]}\n"
                f"  arm: {{type: Arm, model: '{model}', q0: [0]}}\n"
                "connections: [tau.y -> arm.tau]\n")
        with pytest.raises(spidersim.SpidersimError) as ei:
            spidersim.loads(text)
        for w in words:
            assert w in str(ei.value), str(ei.value)


def test_relative_data_file_is_found_beside_the_diagram(tmp_path, monkeypatch):
    """``model: one_link.yaml`` in a diagram file names the file beside the diagram (as a
    subsystem path does), whatever the current folder; ``spider`` keeps naming the shipped
    arm. It was looked up in the current folder: 'arm data file not found'."""
    import spidersim
    folder = tmp_path / "models"
    folder.mkdir()
    (folder / "one_link.yaml").write_text(
        "links:\n  - {d: 0, a: 1, alpha: 0, mass: 1, com: [0.5, 0, 0], "
        "inertia: [0.1, 0.1, 0.1]}\n")
    diagram = folder / "d.yaml"
    diagram.write_text("blocks:\n  tau: {type: Constant, value: [0]}\n"
                       "  arm: {type: Arm, model: one_link.yaml, q0: [0.1]}\n"
                       "connections: [tau.y -> arm.tau]\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    d = spidersim.load(str(diagram))
    assert d.logged_sizes()["arm.q"] == 1          # the one-link arm, not SPIDER's seven
