"""The model library and the command translation, in process (no server)."""
from __future__ import annotations

import numpy as np
import pytest

import spidersim
from spidersim.multibody import Chain
from spidersim.multibody.chain import dh_transform
from spidersim.service.commands import prepare
from spidersim.service.library import BadName, Library, Model, UnknownModel


@pytest.fixture(scope="module")
def lib():
    return Library()


def test_default_library_is_the_shipped_models(lib):
    names = lib.names()
    for n in ("spider", "servo", "payload_capture", "joint_step"):
        assert n in names
    assert "joint" not in names            # a subsystem (exposed inputs), not a model
    assert "lag" not in names              # diagrams/lib is not scanned
    with pytest.raises(BadName):
        lib.get("../spider")
    with pytest.raises(UnknownModel, match="did you mean servo"):
        lib.get("servi")


def test_arm_view_data_is_the_arms_kinematics(lib):
    info = lib.get("spider").info()
    arm = info["arm"]
    assert arm["n"] == 7 and arm["signal"] == "arm.q"
    q0 = np.array(arm["q0"])
    T = np.eye(4)
    for row, q in zip(arm["dh"], q0):           # what the page computes
        T = T @ dh_transform(q, row["d"], row["a"], row["alpha"])
    assert np.allclose(T, Chain.from_yaml().fk(q0), atol=1e-12)
    assert "straight_move" in info["commands"]["named"]
    assert info["commands"]["cartesian_line"][0]["ik"] == "ik"


def test_cartesian_line_sets_ik_and_profile(lib):
    d, t_end = prepare(lib.get("spider"), {"command": {
        "kind": "cartesian_line", "direction": [0, 3, 4], "distance": 0.1, "speed": 0.02}})
    assert np.allclose(d.blocks["ik"].params["direction"], [0, 3, 4])
    p = d.blocks["path"].params
    assert (p["q0"], p["q1"], p["v_max"]) == (0.0, 0.1, 0.02)
    assert t_end == d.simulation["t_end"]            # the model's own run length


def test_joint_path_trapezoid_takes_the_given_time(tmp_path):
    f = tmp_path / "move.yaml"
    f.write_text("blocks:\n  ref: {type: TrapezoidalProfile}\n  g: {type: Gain, k: 1}\n"
                 "connections: [ref.q -> g.u]\nlog: [ref.q, ref.qd]\n")
    m = Model("move", str(f))
    qa, qb, ta, tb = 0.2, -0.4, 0.3, 1.5
    d, _ = prepare(m, {"command": {"kind": "joint_path", "points": [qa, qb],
                                   "times": [ta, tb]}})
    r = d.simulate(t_end=2.0, jit=False, output_interval=0.001)
    q, qd = r["ref.q"], r["ref.qd"]
    assert np.all(q[r.t <= ta] == qa) and np.all(q[r.t >= tb - 1e-12] == pytest.approx(qb))
    moving = (r.t > ta + 1e-9) & (r.t < tb - 1e-9)
    assert np.all(qd[moving] < 0)               # moves all the way, never stops early
    # a third accelerating, a third cruising at 1.5 d/T, a third braking
    v = 1.5 * abs(qb - qa) / (tb - ta)
    cruise = (r.t > ta + (tb - ta) / 3 + 1e-6) & (r.t < tb - (tb - ta) / 3 - 1e-6)
    assert np.allclose(qd[cruise], -v, rtol=1e-12)


def test_joint_path_of_more_points_replaces_the_block_by_a_via_point_profile(tmp_path):
    f = tmp_path / "move.yaml"
    f.write_text("blocks:\n  ref: {type: QuinticProfile}\n  g: {type: Gain, k: 1}\n"
                 "connections: [ref.q -> g.u]\nlog: [ref.q, g.y]\n")
    m = Model("move", str(f))
    q, t = [0.0, 0.4, 1.0, 0.2], [0.1, 0.5, 1.0, 1.6]
    d, _ = prepare(m, {"command": {"kind": "joint_path", "points": q, "times": t}})
    assert d.blocks["ref"].cls.type_name == "ViaPointProfile"
    assert d.blocks["ref"].params["points"].tolist() == q
    assert d.blocks["ref"].params["times"].tolist() == t
    r = d.simulate(t_end=2.0, jit=False)
    for qk, tk in zip(q, t):
        k = np.flatnonzero(r.t == tk)
        assert k.size and r["g.y"][k] == pytest.approx(qk, abs=1e-12)
    # two points keep the block and set its parameters
    d, _ = prepare(m, {"command": {"kind": "joint_path", "points": [0.2, 0.7],
                                   "times": [0.5, 1.5]}})
    assert d.blocks["ref"].cls.type_name == "QuinticProfile"
    p = d.blocks["ref"].params
    assert (p["q0"], p["q1"], p["T"], p["t_start"]) == (0.2, 0.7, 1.0, 0.5)


@pytest.mark.parametrize("cmd,params,needle", [
    ({"points": [0, 1, 2], "times": [0, 1]}, {}, "one time per point, got 3 points and 2"),
    ({"points": [0], "times": [0]}, {}, "at least 2 points"),
    ({"points": [0, 1, 2], "times": [0, 2, 1]}, {}, "strictly increasing from t >= 0"),
    ({"points": [0, 1, 2], "times": [-1, 1, 2]}, {}, "strictly increasing from t >= 0"),
    ({"points": [0, 1, 2], "times": [0, 1, 2]}, {"ref.T": 3.0},
     "parameter 'ref.T' belongs to block 'ref', which a joint_path of more than 2 points"),
    ({"points": [0, 1], "times": [0, 1]}, {"ref.T": 3.0}, "'ref.T' is set by the command"),
])
def test_joint_path_refusals(tmp_path, cmd, params, needle):
    f = tmp_path / "move.yaml"
    f.write_text("blocks:\n  ref: {type: QuinticProfile}\n  g: {type: Gain, k: 1}\n"
                 "connections: [ref.q -> g.u]\n")
    with pytest.raises(spidersim.ParameterError, match=needle.replace(".", r"\.")):
        prepare(Model("move", str(f)), {"command": {"kind": "joint_path", **cmd},
                                        "parameters": params})


def test_malformed_commands_section_names_file_and_line(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("blocks:\n  ref: {type: Step}\n  g: {type: Gain}\nconnections: [ref.y -> g.u]\n"
                 "commands:\n  go:\n    doc: x\n    colour: red\n")
    with pytest.raises(spidersim.ParameterError) as e:
        prepare(Model("bad", str(f)), {"command": {"kind": "named", "name": "go"}})
    assert "bad.yaml:6" in str(e.value) and "unknown key(s) colour" in str(e.value)
    # local runs ignore the section
    assert spidersim.load(str(f)).simulate(t_end=0.1, jit=False).status == "ok"


def test_values_with_units_are_converted(lib):
    """Request values with units land in the model's units (mOhm -> Ohm, deg -> rad, ms ->
    s); a plain number is taken in the declared unit."""
    import math
    servo = lib.get("servo")
    d, _ = prepare(servo, {"parameters": {"motor.R": {"value": 1500, "unit": "mOhm"}},
                           "initial": {"motor.w": {"value": 60, "unit": "rpm"}},
                           "command": {"kind": "table", "time": [0, 1], "value": [0, 90],
                                       "unit": "deg"}})
    assert math.isclose(d.blocks["motor"].params["R"], 1.5)
    assert math.isclose(d.blocks["motor"].params["w0"], 2 * math.pi)
    assert np.allclose(d.blocks["ref"].params["value"], [0, math.pi / 2])
    d, _ = prepare(servo, {"command": {"kind": "named", "name": "position_step", "arguments": {
        "ref.after": {"value": 45, "unit": "deg"}, "ref.t_step": {"value": 200, "unit": "ms"}}}})
    assert math.isclose(d.blocks["ref"].params["after"], math.pi / 4)
    assert math.isclose(d.blocks["ref"].params["t_step"], 0.2)
    d, _ = prepare(lib.get("spider"), {"command": {
        "kind": "cartesian_line", "direction": [1, 0, 0],
        "distance": {"value": 100, "unit": "mm"}, "speed": {"value": 2, "unit": "cm/s"}}})
    p = d.blocks["path"].params
    assert math.isclose(p["q1"], 0.1) and math.isclose(p["v_max"], 0.02)


def test_joint_path_in_degrees(tmp_path):
    import math
    f = tmp_path / "move.yaml"
    f.write_text("blocks:\n  ref: {type: QuinticProfile}\n  m: {type: DCMotor}\n"
                 "  e: {type: Sum, signs: '+-'}\n  v: {type: Gain, k: 1}\n"
                 "connections: [ref.q -> e.u1, m.phi -> e.u2, e.y -> v.u, v.y -> m.v]\n")
    d, _ = prepare(Model("move", str(f)), {"command": {
        "kind": "joint_path", "points": [0, 30, 90], "times": [0, 1, 2], "unit": "deg"}})
    assert np.allclose(d.blocks["ref"].params["points"], np.radians([0, 30, 90]))
    with pytest.raises(Exception, match="does not convert"):
        prepare(Model("move", str(f)), {"command": {
            "kind": "joint_path", "points": [0, 1], "times": [0, 1], "unit": "m"}})


def test_a_request_cannot_make_the_server_read_its_files(tmp_path):
    """The arm's data file is a parameter (``Arm.model``). A request naming a file of the
    server (/etc/passwd, a secret next to the models) must be refused without the file
    being opened: before this check the file was read and its first value came back in
    the error ('expected a number, got <secret>'). Refused by name for the model's own
    blocks, and through a subsystem by the folder restriction (the model's folders only);
    a data file in the model's folder stays usable."""
    import shutil
    from spidersim.multibody.chain import SPIDER
    models, secret = tmp_path / "models", tmp_path / "secret"
    models.mkdir()
    secret.mkdir()
    (secret / "creds.yaml").write_text(
        "links:\n  - {d: TOPSECRET, a: 0, alpha: 0, mass: 1, com: [0,0,0], "
        "inertia: [1,1,1]}\n")
    shutil.copy(SPIDER, models / "my_arm.yaml")
    (models / "inner.yaml").write_text(
        "blocks:\n  tau: {type: Constant, value: [0, 0, 0, 0, 0, 0, 0]}\n"
        "  arm: {type: Arm}\nconnections: [tau.y -> arm.tau]\noutputs: {q: arm.q}\n")
    (models / "flat.yaml").write_text(
        "blocks:\n  tau: {type: Constant, value: [0, 0, 0, 0, 0, 0, 0]}\n"
        "  arm: {type: Arm}\nconnections: [tau.y -> arm.tau]\n")
    (models / "outer.yaml").write_text(
        "subsystems: {inner: inner.yaml}\nblocks:\n  s: {type: inner}\n"
        "  g: {type: Gain, k: 1}\nconnections: [s.q -> g.u]\n")
    flat = Model("flat", str(models / "flat.yaml"))
    outer = Model("outer", str(models / "outer.yaml"))
    for target in ("/etc/passwd", str(secret / "creds.yaml"), "/nonexistent.yaml"):
        with pytest.raises(spidersim.SpidersimError) as ei:
            prepare(flat, {"parameters": {"arm.model": target}})
        msg = flat.public_message(ei.value)
        assert "names a file of the server" in msg and "TOPSECRET" not in msg
        with pytest.raises(spidersim.SpidersimError) as ei:
            prepare(outer, {"parameters": {"s.arm.model": target}})
        msg = outer.public_message(ei.value)
        assert "not among the files this server's models may read" in msg
        assert "TOPSECRET" not in msg and "not found" not in msg
    d, _ = prepare(outer, {"parameters": {"s.arm.model": str(models / "my_arm.yaml")}})
    assert d.blocks["s.arm"].params["model"].endswith("my_arm.yaml")


def test_values_with_units_that_are_not_units_are_refused(lib):
    """A job's parameter in '1e-3 V' ran with V_max = 5 V (pint read 1/e**3 V, e the
    elementary charge): now a ParameterError (422) naming the parameter; 'mV' gives the
    hand value 20 mV = 0.02 V; dB and a rad/s speed given for a Hz parameter alike."""
    servo = lib.get("servo")
    with pytest.raises(spidersim.ParameterError, match="V_max.*a number may only be"):
        prepare(servo, {"parameters": {"V_max": {"value": 20, "unit": "1e-3 V"}}})
    with pytest.raises(spidersim.ParameterError, match="logarithmic"):
        prepare(servo, {"parameters": {"V_max": {"value": 20, "unit": "dB"}}})
    d, _ = prepare(servo, {"parameters": {"V_max": {"value": 20, "unit": "mV"}}})
    assert d.blocks["sat"].params["upper"] == pytest.approx(0.02, rel=1e-14)
    d, _ = prepare(servo, {"initial": {"motor.w": {"value": 0.5, "unit": "Hz"}}})
    assert d.blocks["motor"].params["w0"] == pytest.approx(np.pi, rel=1e-14)   # 0.5 rev/s


def test_command_values_convert_temperatures_with_their_offset():
    """_to_unit: a value in degC for a target in K adds 273.15; for a target the model does
    not fix (the unit would be kept) an offset is refused; Hz -> rad/s is 2 pi."""
    from spidersim.service.commands import _to_unit
    got, unit = _to_unit(np.array([20.0, -273.15]), "degC", "K", "x", None)
    assert unit is None and got == pytest.approx([293.15, 0.0], abs=1e-12)
    got, _ = _to_unit(np.array([1.0]), "Hz", "rad/s", "x", None)
    assert got == pytest.approx([2 * np.pi], rel=1e-14)
    with pytest.raises(spidersim.ParameterError, match="offset"):
        _to_unit(np.array([20.0]), "degC", "?", "x", None)


CMDU = """\
parameters: {T0: 0.2}
blocks:
  st: {type: Step, t_step: T0, after: 1}
  i: {type: Integrator}
  m: {type: DCMotor}
  v: {type: Constant, value: 1}
connections: [st.y -> i.u, v.y -> m.v]
commands:
  go_ms: {arguments: {st.t_step: {unit: ms}}}
  go_min: {arguments: {T0: {unit: min}}}
  go_R: {arguments: {m.R: {unit: mOhm}}}
  go_def: {arguments: {st.t_step: {unit: ms, default: 300}, v.value: {unit: mV, default: 500}}}
  go_K: {arguments: {st.t_step: {unit: K}}}
  go_free: {arguments: [st.t_step]}
"""


@pytest.mark.parametrize("name, args, path, expected", [
    ("go_ms", {"st.t_step": {"value": 500, "unit": "ms"}}, "st.t_step", 0.5),
    ("go_ms", {"st.t_step": 500}, "st.t_step", 0.5),
    ("go_ms", {"st.t_step": {"value": 0.5, "unit": "s"}}, "st.t_step", 0.5),
    ("go_min", {"T0": {"value": 30, "unit": "s"}}, "st.t_step", 30.0),
    ("go_min", {"T0": 0.01}, "st.t_step", 0.6),
    ("go_R", {"m.R": {"value": 2, "unit": "Ohm"}}, "m.R", 2.0),
    ("go_R", {"m.R": 1500}, "m.R", 1.5),
    ("go_def", {}, "st.t_step", 0.3),
    ("go_def", {}, "v.value", 0.5),               # inherited unit the wiring fixes: V
    ("go_free", {"st.t_step": {"value": 250, "unit": "ms"}}, "st.t_step", 0.25),
    ("go_free", {"st.t_step": 2}, "st.t_step", 2.0),
])
def test_named_command_arguments_land_in_the_parameters_unit(tmp_path, name, args, path,
                                                             expected):
    """A named command's argument is converted to the parameter's own unit: 500 ms for a
    Step's t_step (s) was 500 s, a plain 500 declared in ms too, and 0.5 s became 500;
    2 Ohm for m.R declared in mOhm was 2000 Ohm; 30 s for T0 declared in min was 0.5 (read
    in s). A plain number or a default is in the declared unit; without a declared unit a
    plain number is in the parameter's."""
    f = tmp_path / "cmdu.yaml"
    f.write_text(CMDU)
    d, _ = prepare(Model("cmdu", str(f)), {"command": {"kind": "named", "name": name,
                                                        "arguments": args}})
    block, _, param = path.rpartition(".")
    assert np.ravel(d.blocks[block].params[param])[0] == pytest.approx(expected, rel=1e-14)


@pytest.mark.parametrize("name, args, words", [
    ("go_ms", {"st.t_step": {"value": 1, "unit": "m"}},
     "command 'go_ms': argument 'st.t_step': m does not convert to ms .* declares it in ms"),
    ("go_free", {"st.t_step": {"value": 1, "unit": "K"}},
     "argument 'st.t_step': K does not convert to s .*the parameter is in s"),
    ("go_K", {"st.t_step": 3}, "argument 'st.t_step': K does not convert to s"),
    ("go_ms", {"st.t_step": {"value": 1}}, "a value with a unit is"),
])
def test_named_command_argument_units_of_another_kind_are_refused(tmp_path, name, args,
                                                                  words):
    """A unit that does not convert to the declared one or to the parameter's is a
    ParameterError naming the command and the argument (a declared K on a time ran)."""
    f = tmp_path / "cmdu.yaml"
    f.write_text(CMDU)
    with pytest.raises(spidersim.ParameterError, match=words):
        prepare(Model("cmdu", str(f)), {"command": {"kind": "named", "name": name,
                                                     "arguments": args}})


def test_named_command_argument_of_an_open_unit_is_in_the_declared_unit(lib):
    """payload_capture's carry.q1 (a TrapezoidalProfile whose unit the wiring leaves
    open) is declared in m: 10 cm is 0.1, and 2500 ms for the diagram parameter t_latch
    (declared s) is 2.5 s."""
    d, _ = prepare(lib.get("payload_capture"), {"command": {
        "kind": "named", "name": "capture_payload", "arguments": {
            "carry.q1": {"value": 10, "unit": "cm"}, "t_latch": {"value": 2500, "unit": "ms"}}}})
    assert d.blocks["carry"].params["q1"] == pytest.approx(0.1, rel=1e-14)
    assert d.blocks["latch"].params["t_step"] == pytest.approx(2.5, rel=1e-14)
