"""The model library: the runnable diagrams under the service's ``--models`` folders.

Each ``*.yaml`` directly in a folder (or a file named on its own) is a model named after its
file stem (``servo.yaml`` -> ``servo``); files with exposed ``inputs`` are subsystems and are
not listed. The default library is what ships with spidersim: ``spider.yaml`` and
``diagrams/`` next to the package (found from the package's location, so an editable install
works from any folder).

A model's description (``Model.info()``) is read from the diagram and the block declarations:
documentation, parameters (value, unit, bounds, doc), initial states that may be set,
commandable inputs (see :mod:`spidersim.service.commands`), logged signals with units, plots,
and for a diagram with an ``Arm`` block the arm's standard DH table for a 3-D view.
"""
from __future__ import annotations

import glob
import hashlib
import os
import re
import sys
import threading

import numpy as np

import spidersim

NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,63}\Z")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def default_dirs():
    """``spider.yaml`` and ``diagrams/`` of the source tree the package lives in."""
    out = []
    if os.path.isfile(os.path.join(ROOT, "spider.yaml")):
        out.append(os.path.join(ROOT, "spider.yaml"))
    if os.path.isdir(os.path.join(ROOT, "diagrams")):
        out.append(os.path.join(ROOT, "diagrams"))
    return out


class BadName(ValueError):
    """A model name that is not an identifier (e.g. contains ``..`` or ``/``)."""


class UnknownModel(KeyError):
    pass


def _json(v):
    """Plain JSON data; non-finite numbers as the strings "inf", "-inf", "nan" (the
    diagram loader reads those back)."""
    if isinstance(v, np.ndarray):
        return _json(v.tolist())
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return _json(v.item())
    if isinstance(v, float) and not np.isfinite(v):
        return "nan" if np.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, (list, tuple)):
        return [_json(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _json(x) for k, x in v.items()}
    return v


def _is_subsystem(path):
    try:
        spec = spidersim.diagram.spec.parse_file(path)
    except spidersim.SpidersimError:
        return False
    return bool(spec.inputs or spec.outputs)


class Model:
    """One diagram file of the library."""

    def __init__(self, name, path):
        self.name = name
        self.path = path
        self.folder = os.path.dirname(path)
        self._info = None
        self._lock = threading.Lock()

    def file_hash(self):
        with open(self.path, "rb") as fh:
            return hashlib.sha256(fh.read()).hexdigest()

    def spec(self):
        return spidersim.diagram.spec.parse_file(self.path)

    def public_message(self, exc):
        """An error's text with the server's folders left out (file names stay)."""
        text = str(exc)
        for root in {self.folder, ROOT}:
            text = text.replace(root + os.sep, "")
        return text

    def info(self):
        with self._lock:
            if self._info is None:
                self._info = self._describe()
            return self._info

    def _describe(self):
        from .commands import commandables
        d = spidersim.load(self.path)
        spec = d.spec
        blocks = []
        initial = {}
        for path, inst in d.blocks.items():
            cls = inst.cls
            params = []
            for pname, decl in cls.parameters.items():
                bounds = {k: getattr(decl, k) for k in ("gt", "ge", "lt", "le")
                          if getattr(decl, k) is not None}
                params.append({"name": pname, "value": _json(inst.params.get(pname)),
                               "unit": d.units.get((path, "param", pname),
                                                   cls.unit_of(decl)),
                               "doc": decl.doc, "bounds": bounds,
                               "kind": decl.kind, "structural": decl.is_structural,
                               "choices": list(decl.choices) if decl.choices else None})
            blocks.append({"path": path, "type": cls.type_name,
                           "doc": (cls.__doc__ or "").strip().splitlines()[0]
                           if cls.__doc__ else "", "parameters": params})
            for sname, st in cls.states.items():
                if isinstance(st.initial, str) and st.initial in cls.parameters:
                    initial[f"{path}.{sname}"] = {
                        "parameter": f"{path}.{st.initial}",
                        "unit": d.units.get((path, "param", st.initial), cls.unit_of(st)),
                        "value": _json(inst.params.get(st.initial)), "doc": st.doc}
        units = {r[0]: r[4] for r in d._signal_table()}
        signals = [{"name": n, "size": s, "unit": units.get(n, "1")}
                   for n, s in d.logged_sizes().items()]
        plots = [{"title": p.get("title", ""), "kind": p.get("kind", "time"),
                  "signals": list(p.get("signals", []))} for p in spec.plots
                 if isinstance(p, dict)]
        return _json({
            "name": self.name, "file": os.path.basename(self.path), "title": spec.name,
            "description": spec.description.strip(),
            "parameters": [{"name": k, "value": _json(v)} for k, v in spec.parameters.items()],
            "blocks": blocks, "initial": initial,
            "simulation": {k: _json(v) for k, v in d.simulation.items()},
            "signals": signals, "all_signals": len(d.signals()), "plots": plots,
            "commands": commandables(d, spec), "arm": _arm_info(d),
            "n_states": int(d.layout.n_x), "n_blocks": len(d.blocks),
            "hash": self.file_hash(), "version": spidersim.__version__,
        })


def _arm_info(d):
    """DH table, initial angles and link masses of the first Arm block, or None."""
    for path, bl in d.layout.blocks.items():
        if bl.cls.type_name != "Arm":
            continue
        from spidersim.multibody import SPIDER, Chain
        model = bl.params["model"]
        ch = Chain.from_yaml(SPIDER if model == "spider" else model)
        P = ch.P
        return {"block": path, "n": int(ch.n), "convention": "standard DH, "
                "A_i = Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)",
                "dh": [{"d": float(r[0]), "a": float(r[1]), "alpha": float(r[2])} for r in P],
                "mass": [float(r[3]) for r in P],
                "q0": _json(np.ravel(bl.params["q0"])), "signal": f"{path}.q"}
    return None


class Library:
    """Models found in ``dirs`` (folders or single files); the first of a name wins."""

    def __init__(self, dirs=None):
        self.dirs = [os.path.abspath(p) for p in (dirs or default_dirs())]
        self.models = {}
        self.skipped = []
        for entry in self.dirs:
            files = sorted(glob.glob(os.path.join(entry, "*.yaml"))) if os.path.isdir(entry) \
                else [entry] if os.path.isfile(entry) else []
            if not files:
                print(f"spidersim serve: no models in {entry}", file=sys.stderr)
            for f in files:
                name = os.path.splitext(os.path.basename(f))[0]
                if not NAME.match(name):
                    self.skipped.append((f, "file name is not an identifier"))
                elif name in self.models:
                    self.skipped.append((f, f"a model '{name}' came earlier"))
                elif _is_subsystem(f):
                    continue
                else:
                    self.models[name] = Model(name, f)

    def names(self):
        return sorted(self.models)

    def get(self, name) -> Model:
        if not isinstance(name, str) or not NAME.match(name):
            raise BadName(f"model name must be an identifier (letters, digits, '_'; no '/', "
                          f"'.' or '..'), got {name!r}")
        if name not in self.models:
            import difflib
            near = difflib.get_close_matches(name, self.names(), n=3)
            hint = f"; did you mean {', '.join(near)}?" if near else ""
            raise UnknownModel(f"no model '{name}'{hint}; models: {', '.join(self.names())}")
        return self.models[name]
