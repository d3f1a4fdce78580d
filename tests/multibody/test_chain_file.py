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
    # bounds (a hostile review, session 15: com 1e160 m or mass 1e300 kg overflowed the mass
    # matrix, refused as "singular at q = 0 (smallest eigenvalue nan kg m^2)")
    (LINK1.replace("d: 0.3", "d: 2e6").join(["links:\n", "\n"]), 2,
     ["links[0].d: 2e+06 m is beyond the bound of 1e+06 m"]),
    (LINK1.replace("a: 0,", "a: -1.5e6,").join(["links:\n", "\n"]), 2,
     ["links[0].a: 1.5e+06 m is beyond the bound of 1e+06 m"]),
    (LINK1.replace("mass: 4", "mass: 1e300").join(["links:\n", "\n"]), 2,
     ["links[0].mass: 1e+300 kg is beyond the bound of 1e+06 kg", "in m, kg and kg m^2"]),
    (LINK1.join(["links:\n", "\n"]) + LINK1.replace("com: [0, 0, 0.15]", "com: [1e160, 0, 0]")
     + "\n", 3, ["links[1].com: 1e+160 m is beyond the bound of 1e+06 m"]),
    (LINK1.replace("[0.05, 0.05, 0.01]", "[2e18, 2e18, 2e18]").join(["links:\n", "\n"]), 2,
     ["links[0].inertia: 2e+18 kg m^2 is beyond the bound of 1e+18 kg m^2"]),
    (LINK1.replace("[0.05, 0.05, 0.01]", "[[3e18, 0, 0], [0, 3e18, 0], [0, 0, 3e18]]")
     .join(["links:\n", "\n"]), 2, ["links[0].inertia: 3e+18 kg m^2 is beyond"]),
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
    huge = str(tmp_path / "huge.yaml")
    with open(huge, "w") as fh:
        fh.write(LINK1.replace("com: [0, 0, 0.15]", "com: [1e160, 0, 0]").join(["links:\n",
                                                                               "\n"]))
    for model, words in ((str(tmp_path / "none.yaml"), ["not found"]),
                         (bad, ["links[0].com", "3 numbers"]),
                         (huge, [f"{huge}:2: links[0].com: 1e+160 m is beyond the bound"])):
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


def test_values_at_the_bounds_load_and_stay_finite(tmp_path):
    """64 links with every length at 1e6 m, mass 1e6 kg and inertia 1e18 kg m^2 (the
    bounds, included) load: their mass matrix (4e22) is far from overflow."""
    link = ("{d: 1e6, a: -1e6, alpha: pi/2, mass: 1e6, com: [1e6, -1e6, 1e6], "
            "inertia: [1e18, 1e18, 1e18]}")
    ch = Chain.from_yaml(_write(tmp_path, "links: [" + ", ".join([link] * 64) + "]\n"))
    M = ch.mass_matrix(np.zeros(64))
    assert np.all(np.isfinite(M)) and np.abs(M).max() < 1e25


def test_overflowing_mass_matrix_names_the_cause():
    """A chain built in Python has no bounds: a mass matrix that overflows is said to be
    one, naming the largest length, mass and inertia (it was 'singular ... eigenvalue
    nan')."""
    ch = Chain([[0.3, 0, np.pi / 2], [0.3, 0, np.pi / 2]], [1.0, 2.0],
               [[0, 0.1, 0.3], [1e160, 0, 0]], [[0.1, 0.1, 0.1], [0.2, 0.2, 0.2]])
    with pytest.raises(DiagramError) as ei:
        ch._check_inertia("arm.yaml")
    msg = str(ei.value)
    assert msg.startswith("arm.yaml: the chain's joint-space mass matrix at q = 0 is not "
                          "finite (it overflowed): a mass, length or inertia is too large"), msg
    assert ("the largest are links[1].com 1e+160 m, links[1].mass 2 kg, links[1].inertia "
            "0.2 kg m^2") in msg, msg
    assert "singular" not in msg
