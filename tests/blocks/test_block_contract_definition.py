"""The block contract is checked when a block class is defined (issue #17 item 5): a wrong
kernel argument fails at once, naming the class and the argument, not at code generation."""
import pytest

from spidersim.blocks import REGISTRY
from spidersim.blocks.base import Block, BlockDefinitionError, Event, Mode, Param, Port, State


def _define(**body):
    return type("Bad" + str(len(body)), (Block,), dict(category="test", **body))


def test_unknown_kernel_argument_names_class_and_argument():
    with pytest.raises(BlockDefinitionError, match=r"class Lag: kernel 'derivative' argument "
                                                    r"'tauu' .* \(did you mean tau\?\)"):
        class Lag(Block):
            parameters = {"tau": Param(1.0, "s")}
            inputs = {"u": Port()}
            outputs = {"y": Port()}
            states = {"y": State()}

            @staticmethod
            def derivative(t, y, u, tauu, der_y):
                der_y[0] = (u[0] - y[0]) / tauu
    assert "Lag" not in REGISTRY


@pytest.mark.parametrize("body,words", [
    (dict(parameters={"k": Param(1.0)}, inputs={"k": Port()}), "both as parameter and as input"),
    (dict(states={"der_x": State()}), "reserved prefix der_"),
    (dict(outputs={"y": Port()}, derivative=staticmethod(lambda t, der_y: None)),
     "declares no states"),
    (dict(inputs={"u": Port()}, events={"hit": Event(1)},
          guard=staticmethod(lambda t, u, zc: None)), "both 'guard' and 'on_event'"),
    (dict(parameters={"direction": Param(1.0)}, inputs={"u": Port()}, outputs={"y": Port()},
          output=staticmethod(lambda t, u, direction, y: None)), "ambiguous"),
    (dict(outputs={"y": Port()}, output=lambda t, y: None), "@staticmethod"),
    (dict(outputs={"z": Port()}, parameters={"z0": Param(0.0)}, implicit={"z": ("r", "z0")}),
     "residual port 'r'"),
    (dict(outputs={"y": Port()}, modes={"h": Mode()},
          time_output=staticmethod(lambda t, h: None)), "'time_output' but not both"),
    (dict(inputs={"u": Port()}, outputs={"y": Port()}, modes={"h": Mode()},
          next_time=staticmethod(lambda t, h: 0.0),
          time_event=staticmethod(lambda t, u, h: None),
          time_output=staticmethod(lambda t, u, h: None)), "'time_output' argument 'u'"),
])
def test_contract_violations(body, words):
    with pytest.raises(BlockDefinitionError, match=words):
        _define(**body)


def test_derived_names_are_accepted():
    class Scaled(Block):
        type_name = "_TestScaled"
        parameters = {"k": Param(2.0)}
        inputs = {"u": Port()}
        outputs = {"y": Port(feedthrough=("u",))}

        @classmethod
        def derive(cls, params):
            return {"k2": float(params["k"]) ** 2}

        @staticmethod
        def output(t, u, k2, y):
            y[0] = k2 * u[0]
    assert REGISTRY.pop("_TestScaled") is Scaled


def test_every_library_block_passes():
    assert len(REGISTRY) > 40      # all of them were checked when the package was imported


@pytest.mark.parametrize("body,words", [
    (dict(inputs={"u": Port()}, outputs={"y": Port(feedthrough=("u",))},
          partials=staticmethod(lambda t, u: None)), "takes none of dfdx"),
    (dict(inputs={"u": Port()}, outputs={"y": Port(feedthrough=("u",))},
          partials=staticmethod(lambda t, dfdx: None)), "'dfdx' but the block declares no "
                                                         "states"),
    (dict(inputs={"u": Port()}, outputs={"y": Port()}, states={"y": State()},
          derivative=staticmethod(lambda t, u, der_y: None),
          partials=staticmethod(lambda t, dydu: None)), "no outputs that are not states"),
    (dict(outputs={"y": Port()}, states={"x": State()},
          derivative=staticmethod(lambda t, der_x: None),
          partials=staticmethod(lambda t, dfdu: None)), "no states and inputs"),
    (dict(inputs={"u": Port()}, outputs={"y": Port()}, states={"y": State()},
          derivative=staticmethod(lambda t, u, der_y: None),
          partials=staticmethod(lambda t, der_y, dfdu: None)), "'der_y' is not available"),
    (dict(inputs={"u": Port()}, outputs={"y": Port(feedthrough=("u",))},
          partials=staticmethod(lambda t, kk, dydu: None)), "argument 'kk'"),
    (dict(parameters={"dydu": Param(1.0)}), "'dydu' is reserved"),
    (dict(inputs={"u": Port()}, outputs={"y": Port(feedthrough=("u",))},
          partials=lambda t, dydu: None), "@staticmethod"),
])
def test_partials_kernel_violations(body, words):
    """The ``partials`` kernel (contract item 4) is checked at class definition: it takes
    at least one of its matrices, only those the block can have, no event or derivative
    arguments, only declared names; the matrix names are reserved."""
    with pytest.raises(BlockDefinitionError, match=words):
        _define(**body)


def test_partials_kernel_accepted():
    """A well-formed ``partials`` kernel (a first-order lag) defines a block."""
    class _Lag(Block):
        type_name = "_TestLag"
        parameters = {"tau": Param(1.0, "s")}
        inputs = {"u": Port()}
        outputs = {"y": Port()}
        states = {"y": State()}

        @staticmethod
        def derivative(t, y, u, tau, der_y):
            der_y[0] = (u[0] - y[0]) / tau

        @staticmethod
        def partials(t, tau, dfdx, dfdu):
            dfdx[0, 0] = -1.0 / tau
            dfdu[0, 0] = 1.0 / tau
    assert REGISTRY.pop("_TestLag") is _Lag


def test_declared_derives_replace_the_call_on_the_defaults():
    """A block whose ``derive`` is costly on its defaults (the arm blocks read a model file
    and build the kinematic chain) declares ``derives``: defining the class does not call
    ``derive`` (here it would raise), the kernel arguments are checked against the declared
    names (an undeclared one is refused), and :meth:`Block.derived` refuses a ``derive``
    returning other names than declared."""
    def derive(cls, params):
        if params["k"] == 1.0:
            raise RuntimeError("derive was called with the defaults")
        return {"k2": 2 * params["k"]} if params["k"] > 0 else {"other": 0.0}

    body = dict(parameters={"k": Param(1.0)}, inputs={"u": Port()},
                outputs={"y": Port(feedthrough=("u",))}, derives=("k2",),
                derive=classmethod(derive),
                output=staticmethod(lambda t, u, k2, y: None))
    cls = _define(**body)
    assert REGISTRY.pop(cls.type_name) is cls
    assert cls.derived({"k": 3.0}) == {"k2": 6.0}
    with pytest.raises(BlockDefinitionError, match=r"derive returned \['other'\], the "
                                                   r"class declares derives = \['k2'\]"):
        cls.derived({"k": -1.0})
    with pytest.raises(BlockDefinitionError, match=r"argument 'k3'"):
        _define(**dict(body, output=staticmethod(lambda t, u, k3, y: None)))


def test_the_arm_blocks_declare_what_derive_returns():
    """The declared ``derives`` of the arm and force-control blocks are what their
    ``derive`` returns (the check the definition skips; a mismatch raises in ``derived``),
    with the defaults and a seven-joint ``q0`` where the block has one."""
    declared = [c for c in REGISTRY.values() if c.derives is not None]
    assert {c.type_name for c in declared} >= {"Arm", "CartesianLineIK", "ForwardKinematics",
                                               "Jacobian", "HybridForceController"}
    for cls in declared:
        user = {"q0": [0.0, 0.5, 0.0, -1.0, 0.0, 0.6, 0.0]} if "q0" in cls.parameters else {}
        params = cls.validate_params(user)
        assert set(cls.derive(params)) == set(cls.derives), cls.type_name
