"""Test harness: one block, fed by Constant blocks, evaluated through the compiled system.

``Probe("Gain", {"k": 2.0}, sizes={"u": 3})`` builds (as YAML text, through
``spidersim.loads``) the diagram::

    blk:  {type: Gain, k: 2.0}
    in_u: {type: Constant, value: [0, 0, 0]}      one Constant per input of blk
    in_u.y -> blk.u

and compiles it in interpreted mode (``jit=False``). Then::

    p.set_input("u", [1, 2, 3])     # d.set("in_u.value", ...), copied into the system
    x = p.x0()                      # initial flat state vector (a copy)
    p.set_state(x, "y", [...])      # write one state of blk into x
    p.initialize(t, x)              # let mode blocks take the modes their inputs imply
    p.outputs(t, x)                 # {output name: array} of blk at time t
    p.derivatives(t, x)             # {state name: array} of blk at time t

Every input gets a Constant, optional ones included (so that they can be perturbed); input
sizes default to 1 unless given in ``sizes``. Modes are left as they are (the initial modes)
unless ``initialize`` or ``set_mode`` is called: outputs are a function of (t, x, inputs,
modes), as the schedule sees them between events.

For blocks that cannot stand alone (an ``AlgebraicConstraint`` needs a loop), ``extra``
adds blocks (name -> (type, params)), ``feed`` connects an input to one of their outputs
instead of a Constant (input -> "block.port") and ``wires`` adds connections.
"""
from __future__ import annotations

import numpy as np
import yaml

import spidersim
from spidersim.blocks import REGISTRY


def block_yaml(name, type_name, params):
    """One ``name: {type: ..., ...}`` line of a diagram (values YAML-encoded)."""
    entry = {"type": type_name}
    entry.update({k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v)
                  for k, v in params.items()})
    return f"  {name}: " + yaml.safe_dump(entry, default_flow_style=True, width=10**6).strip()


class Probe:
    """One block ``blk`` of type ``type_name`` with every input fed by a Constant."""

    def __init__(self, type_name, params=None, sizes=None, extra=None, feed=None, wires=()):
        self.cls = REGISTRY[type_name]
        self.params = dict(params or {})
        feed = dict(feed or {})
        names = self.cls.input_names(self.cls.validate_params(dict(self.params)))
        #: inputs fed by a Constant ``in_<name>`` (the ones set_input can set)
        self.inputs = [n for n in names if n not in feed]
        self.sizes = {n: int((sizes or {}).get(n, 1)) for n in self.inputs}
        lines = ["name: probe", "blocks:", block_yaml("blk", type_name, self.params)]
        lines += [block_yaml(f"in_{n}", "Constant", {"value": [0.0] * s})
                  for n, s in self.sizes.items()]
        lines += [block_yaml(n, t, prm) for n, (t, prm) in (extra or {}).items()]
        conns = [f"in_{n}.y -> blk.{n}" for n in self.inputs]
        conns += [f"{src} -> blk.{n}" for n, src in feed.items()] + list(wires)
        if conns:
            lines += ["connections:"] + [f"  - {c}" for c in conns]
        self.yaml = "\n".join(lines) + "\n"
        self.d = spidersim.loads(self.yaml)
        with np.errstate(all="ignore"):  # the warm-up call sees all-zero inputs (0/0)
            self.system = self.d.compile(jit=False)
        self.layout = self.d.layout.blocks["blk"]
        self.outputs_names = list(self.layout.outputs)
        self.state_names = [s for s, (a, b) in self.layout.states.items() if b > a]

    # ---------------------------------------------------------------- inputs, states, modes
    def set_input(self, name, value):
        """Set input ``name`` (through its Constant) to ``value`` (scalar or array)."""
        value = np.broadcast_to(np.asarray(value, dtype=float), (self.sizes[name],))
        self.d.set(f"in_{name}.value", np.array(value))
        self._sync_p()

    def set_param(self, name, value, block="blk"):
        """Change a numeric parameter of the block (no recompilation)."""
        self.d.set(f"{block}.{name}", value)
        self._sync_p()

    def _sync_p(self):
        """Copy the diagram's parameters into the system's copy, keeping the loop solver's
        tolerances that ``compile`` wrote there (not in the diagram's array)."""
        tol = self.d.layout.p_loop_tol
        kept = self.system.p[list(tol)].copy()
        self.system.p[:] = self.d.p
        if tol != (0, 0):
            self.system.p[list(tol)] = kept

    def x0(self):
        """Initial flat state vector of the diagram (a copy)."""
        return self.system.x0.copy()

    def state_slice(self, name):
        a, b = self.layout.states[name]
        return slice(a, b)

    def set_state(self, x, name, value):
        """Write state ``name`` of the block into the flat state vector ``x`` (in place)."""
        x[self.state_slice(name)] = value
        return x

    def mode(self, name):
        a, b = self.layout.modes[name]
        return self.system.modes[a:b].copy()

    def set_mode(self, name, value):
        a, b = self.layout.modes[name]
        self.system.modes[a:b] = value

    def initialize(self, t=0.0, x=None):
        """Run the blocks' ``initialize`` hooks (as at the start and after an event)."""
        x = self.x0() if x is None else np.asarray(x, dtype=float)
        self.outputs(t, x)
        self.system.initialize(t, x)

    # ---------------------------------------------------------------- evaluation
    def outputs(self, t=0.0, x=None):
        """``{output: array copy}`` of the block at time ``t`` and flat state ``x``.

        ``system.outputs`` is called twice: a block whose output declares no feedthrough may
        be scheduled before the Constants that feed it, and must then still see the current
        input values if it (wrongly) reads them.
        """
        x = self.x0() if x is None else np.asarray(x, dtype=float)
        self.system.outputs(t, x)
        self.system.outputs(t, x)
        out = {}
        for o in self.outputs_names:
            arr, a, b = self.layout.ports[("out", o)].loc
            out[o] = (self.system.sig if arr == "sig" else x)[a:b].copy()
        return out

    def derivatives(self, t=0.0, x=None):
        """``{state: array}`` of the block's state derivatives at ``t``, ``x``."""
        x = self.x0() if x is None else np.asarray(x, dtype=float)
        self.system.outputs(t, x)
        xdot = self.system.rhs(t, x)
        return {s: xdot[self.state_slice(s)].copy() for s in self.state_names}


def simulate(text, **kw):
    """Load a diagram from YAML ``text`` and simulate it interpreted (``jit=False``)."""
    kw.setdefault("jit", False)
    return spidersim.loads(text).simulate(**kw)
