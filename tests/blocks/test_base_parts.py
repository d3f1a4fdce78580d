"""The parts of the Block base class (spidersim.blocks.base), each alone on tiny classes.

The classes here are declared with ``abstract=True``: they are neither registered nor checked
when defined, so each part of the contract check can be called on them directly. No kernel is
compiled. The whole check on every library block is test_block_contract_definition.py; the
numeric contract probe is test_contract.py.
"""
import numpy as np
import pytest

from spidersim.blocks import base as B
from spidersim.blocks.base import (REGISTRY, REQUIRED, Block, BlockDefinitionError, Dim, Event,
                                   Mode, Param, Port, State)


class Lag(Block, abstract=True):
    """A first-order lag, well declared: the output ``y`` is the state ``y``."""

    parameters = {"tau": Param(1.0, "s", gt=0)}
    inputs = {"u": Port()}
    outputs = {"y": Port()}
    states = {"y": State()}

    @staticmethod
    def derivative(t, y, u, tau, der_y):
        der_y[0] = (u[0] - y[0]) / tau


def fail(msg):
    """The ``fail`` callback of the normalisers: raise with the message."""
    raise ValueError(msg)


def test_declared_roles_let_an_output_be_its_state():
    """An output with the name of a state is that state (first role kept); any other name
    declared twice is refused naming both roles."""
    assert B._declared_roles(Lag) == {"tau": "parameter", "u": "input", "y": "output"}

    class Twice(Lag, abstract=True):
        modes = {"u": Mode()}
    with pytest.raises(BlockDefinitionError, match="block class Twice: 'u' is declared both "
                                                   "as input and as mode"):
        B._declared_roles(Twice)


def test_kernel_arguments_accept_derivatives_and_suggest_near_names():
    """``der_<state>`` and reserved names are valid kernel arguments; a misspelt one is
    refused with the nearest declared names."""
    roles = B._declared_roles(Lag)
    B._check_kernel_args(Lag, "derivative", Lag.derivative, roles, set())

    def bad(t, y, u, tauu, der_y):
        pass
    with pytest.raises(BlockDefinitionError, match=r"argument 'tauu' .* \(did you mean tau\?\)"):
        B._check_kernel_args(Lag, "derivative", bad, roles, set())
    B._check_kernel_args(Lag, "derivative", bad, roles, {"tauu"})   # a derived name
    B._check_kernel_args(Lag, "derivative", bad, roles, None)       # derived names unknown


def test_derived_names_from_the_defaults():
    """``derive`` is called on the defaults (real ones as arrays) to learn the derived
    names; without ``derive`` there are none; with a required parameter, or a ``derive``
    that fails on the defaults, they are unknown (None) and nothing is refused."""
    assert B._derived_names(Lag) == set()

    class Squared(Lag, abstract=True):
        @classmethod
        def derive(cls, params):
            assert isinstance(params["tau"], np.ndarray)
            return {"tau2": params["tau"] ** 2}
    assert B._derived_names(Squared) == {"tau2"}

    class Required(Squared, abstract=True):
        parameters = {"tau": Param(REQUIRED, "s")}
    assert B._default_params(Required) is None
    assert B._derived_names(Required) is None

    class Failing(Squared, abstract=True):
        parameters = {"tau": Param("x", "s", kind="str")}
    assert B._derived_names(Failing) is None


def test_kernel_set_and_renames_and_implicit_outputs():
    """Events need guard and on_event; a rename needs the new name declared and not the old;
    an implicit output needs a residual port and a guess parameter."""
    class Evented(Lag, abstract=True):
        events = {"hit": Event(1)}

        @staticmethod
        def guard(t, y, zc):
            zc[0] = y[0]
    with pytest.raises(BlockDefinitionError, match="both 'guard' and 'on_event'"):
        B._check_kernel_set(Evented)

    class Renamed(Lag, abstract=True):
        renamed = {"T": "tau"}
    B._check_renamed(Renamed)

    class BadRename(Lag, abstract=True):
        renamed = {"tau": "T"}
    with pytest.raises(BlockDefinitionError, match="'tau' -> 'T' needs 'T' declared"):
        B._check_renamed(BadRename)

    class Implicit(Lag, abstract=True):
        implicit = {"y": ("u", "tau")}
    B._check_implicit(Implicit)

    class BadImplicit(Lag, abstract=True):
        implicit = {"y": ("r", "tau")}
    with pytest.raises(BlockDefinitionError, match="residual port 'r'"):
        B._check_implicit(BadImplicit)


def test_kernels_must_be_static_unless_names_are_dynamic():
    """A kernel that is a plain function is refused; a block with dynamic names (its own
    ``input_names``) skips the argument check but not the staticmethod check."""
    class Plain(Lag, abstract=True):
        def output(t, y):  # noqa: N805
            pass
    with pytest.raises(BlockDefinitionError, match="'output' must be a @staticmethod"):
        B._check_kernels(Plain, B._declared_roles(Plain), set())

    class Dynamic(Lag, abstract=True):
        @classmethod
        def input_names(cls, params):
            return ["u1", "u2"]

        @staticmethod
        def output(t, u1, u2, y):
            pass
    assert B._has_dynamic_names(Dynamic) and not B._has_dynamic_names(Lag)
    B._check_kernels(Dynamic, B._declared_roles(Dynamic), set())


def test_normalise_vector_repeats_a_scalar_and_checks_the_size():
    """A vector parameter of size n accepts a scalar (repeated n times) and n values; other
    lengths and empty lists are refused with the size expected."""
    np.testing.assert_array_equal(Block._normalise_vector(3, np.asarray(2.0), {}, fail),
                                  [2.0, 2.0, 2.0])
    np.testing.assert_array_equal(Block._normalise_vector("n", np.asarray([1.0, 2.0]),
                                                          {"n": 2}, fail), [1.0, 2.0])
    with pytest.raises(ValueError, match=r"must have 3 elements \(3\), got 2"):
        Block._normalise_vector(3, np.asarray([1.0, 2.0]), {}, fail)
    with pytest.raises(ValueError, match="must not be empty"):
        Block._normalise_vector("*", np.asarray([]), {}, fail)


def test_normalise_matrix_reads_flat_lists_as_rows_or_columns():
    """A flat list is one row when one row is declared, otherwise a column; the declared
    row and column counts (from ints, parameters or Dims) are checked."""
    row = Block._normalise_matrix((1, "*"), np.asarray([1.0, 2.0, 3.0]), {}, fail)
    col = Block._normalise_matrix(("*", 1), np.asarray([1.0, 2.0, 3.0]), {}, fail)
    assert row.shape == (1, 3) and col.shape == (3, 1)
    dims = (Dim("n", lambda p: p["n"]), "m")
    assert Block._normalise_matrix(dims, np.ones((2, 3)), {"n": 2, "m": [0, 0, 0]},
                                   fail).shape == (2, 3)
    with pytest.raises(ValueError, match=r"must have 2 columns \(m\), got shape \(2, 3\)"):
        Block._normalise_matrix(("*", "m"), np.ones((2, 3)), {"m": 2}, fail)


def test_size_messages_print_the_dimension_text():
    """A size computed from parameters is named by its text in the message (``joints``),
    not by the Dim object's dump with a function address."""
    joints = Dim("joints", lambda p: 7)
    with pytest.raises(ValueError, match=r"must have 7 elements \(joints\), got 3$") as ei:
        Block._normalise_vector(joints, np.ones(3), {}, fail)
    assert "function" not in str(ei.value) and "Dim(" not in str(ei.value)
    with pytest.raises(ValueError, match=r"must have 7 rows \(joints\), got shape") as ei:
        Block._normalise_matrix((joints, "*"), np.ones((2, 2)), {}, fail)
    assert "function" not in str(ei.value)


def test_as_float_array_refuses_booleans_and_strings():
    """Booleans (alone or inside a list) and strings are not numbers for a real parameter;
    overflowing numbers become inf (refused later by the finiteness check)."""
    for bad, words in ((True, "got a boolean"), ([1, False], "got a boolean"),
                       ("2", "got the string '2'"), ({"a": 1}, "must be numeric")):
        with pytest.raises(ValueError, match=words):
            Block._as_float_array(bad, fail)
    with pytest.raises(ValueError, match="must be finite"):
        Block._check_finite(Param(), Block._as_float_array(1e400, fail), 1e400, fail)
    Block._check_finite(Param(allow_inf=True), np.asarray(np.inf), np.inf, fail)


def test_normalise_bool_str_int():
    """bool takes true/false and 0/1 only; str must be one of its choices (nearest one
    suggested); int must have an integer value and respect the bounds."""
    assert Block._normalise_bool(1, fail) is True
    with pytest.raises(ValueError, match="true or false, got 2"):
        Block._normalise_bool(2, fail)
    decl = Param("a", kind="str", choices=("linear", "cubic"))
    with pytest.raises(ValueError, match=r"got 'cubc' \(did you mean 'cubic'\?\)"):
        Block._normalise_str(decl, "cubc", fail)
    assert Block._normalise_int(Param(1, kind="int", ge=1), np.asarray(3.0), 3.0, fail) == 3
    with pytest.raises(ValueError, match="must be >= 1, got 0"):
        Block._normalise_int(Param(1, kind="int", ge=1), np.asarray(0.0), 0, fail)


def test_describe_lines():
    """The documentation lines of one declaration each: sizes, bounds, feedthrough and
    optional inputs in words."""
    assert [B._size_text(s) for s in (7, None, "@u", Dim("joints", len))] == [
        "7", "inherited", "size of u", "joints"]
    assert B._bounds_text(Param(gt=0, le=1.5)) == ", > 0 and <= 1.5"
    assert B._feedthrough_text(("u", "w")) == "; direct feedthrough from u, w"
    assert B._feedthrough_text(()) == ""
    assert B._describe_param(Lag, "tau", Lag.parameters["tau"]) == \
        "    tau [s] (default 1.0, > 0): "
    assert B._describe_port(Lag, "u", Port("V", 3, "drive", optional=True), output=False) == \
        "    u [V] (size 3, optional: zero when unconnected): drive"
    assert B._describe_section("Modes", {}, B._describe_mode) == []
    assert "Lag" not in REGISTRY
