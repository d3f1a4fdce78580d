"""Signal routing: mux (concatenate), demux (split) and selector (pick elements)."""
import numpy as np

from .base import Block, FromInputs, Param, Port


class Mux(Block):
    """Concatenate inputs ``u1 .. un`` into one vector ``y``."""

    category = "routing"
    parameters = {"n": Param(2, kind="int", ge=1, le=1000, doc="number of inputs")}
    inputs = {"u1": Port("*", size=None, doc="inputs u1 .. un")}
    outputs = {"y": Port("*", size=FromInputs("sum of input sizes",
                                              lambda p, s: sum(s.values())),
                         feedthrough="all", doc="concatenation; unit: the inputs' unit when "
                         "they all have the same one (else a vector of mixed units)")}

    @classmethod
    def input_names(cls, params):
        return [f"u{i + 1}" for i in range(params["n"])]

    @classmethod
    def unit_relations(cls, params):
        return [("common", "y", cls.input_names(params))]

    @classmethod
    def input_decl(cls, name):
        return cls.inputs["u1"]

    @classmethod
    def kernel_source(cls, params, kernel):
        if kernel != "output":
            return None
        names = cls.input_names(params)
        body = ["    k = 0"]
        for n in names:
            body += [f"    for i in range({n}.size):", f"        y[k + i] = {n}[i]",
                     f"    k += {n}.size"]
        return f"def output(t, {', '.join(names)}, y):\n" + "\n".join(body) + "\n"

    @staticmethod
    def output(t, u1, u2, y):
        for i in range(u1.size):
            y[i] = u1[i]
        for i in range(u2.size):
            y[u1.size + i] = u2[i]

    @staticmethod
    def partials(t, dydu):
        """The identity: ``y`` is the inputs one after the other."""
        for i in range(dydu.shape[0]):
            dydu[i, i] = 1.0


class Demux(Block):
    """Split ``u`` into outputs ``y1 .. yk`` of the given sizes."""

    category = "routing"
    parameters = {"sizes": Param(doc="size of each output", shape="*", ge=1, le=1e6,
                                 structural=True)}
    inputs = {"u": Port("*", size=None, doc="vector to split")}
    outputs = {"y1": Port("*", size=None, feedthrough=("u",), doc="outputs y1 .. yk")}

    @classmethod
    def check(cls, params):
        s = params["sizes"]
        if np.any(s != np.round(s)):
            raise ValueError(f"sizes must be integers, got {list(s)}")

    @classmethod
    def check_sizes(cls, params, sizes):
        total = int(params["sizes"].sum())
        if sizes["u"] != total:
            raise ValueError(f"input 'u' has size {sizes['u']} but sizes add up to {total}")

    @classmethod
    def output_names(cls, params):
        return [f"y{i + 1}" for i in range(len(params["sizes"]))]

    @classmethod
    def unit_relations(cls, params):
        return [("copy", y, ["u"]) for y in cls.output_names(params)]

    @classmethod
    def output_decl(cls, name):
        k = int(name[1:]) - 1
        return Port("*", size=Dim_k(k), feedthrough=("u",), doc=f"element group {k + 1}")

    @classmethod
    def kernel_source(cls, params, kernel):
        if kernel != "output":
            return None
        names = cls.output_names(params)
        body, k = [], 0
        for n, s in zip(names, params["sizes"].astype(int)):
            body += [f"    for i in range({s}):", f"        {n}[i] = u[{k} + i]"]
            k += s
        return f"def output(t, u, {', '.join(names)}):\n" + "\n".join(body) + "\n"

    @staticmethod
    def output(t, u, y1):
        for i in range(y1.size):
            y1[i] = u[i]

    @staticmethod
    def partials(t, dydu):
        """The identity: the outputs ``y1 .. yk`` one after the other are ``u``."""
        for i in range(dydu.shape[0]):
            dydu[i, i] = 1.0


def Dim_k(k):
    from .base import Dim
    return Dim(f"sizes[{k}]", lambda p: int(p["sizes"][k]))


class Selector(Block):
    """``y[j] = u[index[j]]`` with 0-based indices."""

    category = "routing"
    parameters = {"index": Param(doc="0-based indices of the elements to pick", shape="*",
                                 ge=0, structural=True)}
    inputs = {"u": Port("*", size=None, doc="input vector")}
    outputs = {"y": Port("*", size=FromInputs("len(index)", lambda p, s: len(p["index"])),
                         feedthrough=("u",), doc="selected elements (the unit of u)")}

    @classmethod
    def unit_relations(cls, params):
        return [("copy", "y", ["u"])]

    @classmethod
    def check_sizes(cls, params, sizes):
        idx = params["index"]
        if np.any(idx != np.round(idx)) or np.any(idx >= sizes["u"]):
            raise ValueError(f"index must hold integers below the input size {sizes['u']}, "
                             f"got {[float(i) for i in idx]}")

    @staticmethod
    def output(t, index, u, y):
        for j in range(y.size):
            y[j] = u[int(index[j])]

    @staticmethod
    def partials(t, index, dydu):
        """``dy_j / du_index[j] = 1``."""
        for j in range(dydu.shape[0]):
            dydu[j, int(index[j])] = 1.0


class UnitCast(Block):
    """``y = u``, the numbers unchanged, read in the unit ``unit``: a deliberate
    reinterpretation that unit checking would otherwise refuse (a dimensionless command
    taken as a current set point, a normalised force fed to a torque input).

    No scaling is applied: ``unit: mm`` on a signal in ``m`` relabels it, it does not multiply
    by 1000. The input takes any unit. A temperature scale with an offset (``degC``,
    ``degF``) is refused: the blocks downstream multiply, integrate and add the signal by
    factors (2 x 20 degC is not 40 degC, 20 degC + 300 K is not 320 K); use ``K``, or
    ``delta_degC`` for a temperature difference.
    """

    category = "routing"
    parameters = {"unit": Param(kind="str", doc="unit of the output, e.g. 'A' or 'N.m'")}
    inputs = {"u": Port("*", size=None, doc="input, any unit")}
    outputs = {"y": Port(lambda p: p["unit"], size="@u", feedthrough=("u",),
                         doc="the input in the unit 'unit'")}

    @classmethod
    def check(cls, params):
        from ..text.units import UnitError, check_no_offset, parse
        try:
            check_no_offset(parse(params["unit"]), "a signal (multiplied, integrated and "
                                                   "added by factors: 2 x 20 degC is not "
                                                   "40 degC)")
        except UnitError as exc:
            raise ValueError(f"parameter 'unit': {exc}") from None

    @staticmethod
    def output(t, u, y):
        for i in range(y.size):
            y[i] = u[i]

    @staticmethod
    def partials(t, dydu):
        """The identity (the numbers are unchanged)."""
        for i in range(dydu.shape[0]):
            dydu[i, i] = 1.0
