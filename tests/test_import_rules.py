"""DESIGN.md's import rules, checked on the package's source (no import is executed).

- no import cycle between spidersim's modules (imports inside functions count too: a cycle
  hidden in a function is still a cycle of knowledge);
- ``solver/`` imports neither ``blocks/`` nor ``diagram/``;
- ``blocks/`` imports neither ``diagram/`` nor ``solver/``;
- ``multibody/`` imports neither (only the neutral ``text/`` layer and ``errors``);
- ``text/`` imports nothing of spidersim but ``errors``;
- nothing outside ``service/`` imports ``service/`` (it uses the public API like any user).
"""
import ast
import os

import networkx as nx
import pytest

PKG = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "spidersim")


def _module_name(path):
    rel = os.path.relpath(path, os.path.dirname(PKG))[:-3].replace(os.sep, ".")
    return rel[:-9] if rel.endswith(".__init__") else rel


def _imports():
    """``{module: {imported spidersim module, ...}}`` for every module of the package."""
    mods = {}
    for d, _, files in os.walk(PKG):
        for f in files:
            if f.endswith(".py"):
                mods[_module_name(os.path.join(d, f))] = os.path.join(d, f)
    out = {}
    for name, path in mods.items():
        is_pkg = path.endswith("__init__.py")
        base = name.split(".") if is_pkg else name.split(".")[:-1]
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read())
        deps = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    parts = base[:len(base) - node.level + 1]
                    target = ".".join(parts + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                cands = [target] + [f"{target}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                cands = [a.name for a in node.names]
            else:
                continue
            for c in cands:
                if c in mods:
                    deps.add(c)
                elif c.startswith("spidersim") and c.rsplit(".", 1)[0] in mods:
                    deps.add(c.rsplit(".", 1)[0])
        deps.discard(name)
        out[name] = deps
    return out


IMPORTS = _imports()


def _layer(mod):
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_imports_were_found():
    """The parser sees the package (a rule test that reads nothing cannot fail)."""
    assert "spidersim.diagram.flatten" in IMPORTS
    assert "spidersim.text.expr" in IMPORTS["spidersim.diagram.flatten"]


def test_no_import_cycles():
    g = nx.DiGraph([(a, b) for a, deps in IMPORTS.items() for b in deps])
    # a package's __init__ re-exporting its own submodules is not a cycle of knowledge
    g.remove_edges_from([(a, b) for a, b in list(g.edges) if b.startswith(a + ".")])
    cycles = [c for c in nx.simple_cycles(g)]
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c + [c[0]]) for c in cycles[:5])


RULES = [
    ("solver", {"blocks", "diagram", "service", "multibody"}),
    ("blocks", {"diagram", "solver", "service"}),
    ("multibody", {"diagram", "solver", "blocks", "service"}),
    ("text", {"diagram", "solver", "blocks", "multibody", "service"}),
    ("diagram", {"service"}),
]


@pytest.mark.parametrize("layer,forbidden", RULES, ids=[r[0] for r in RULES])
def test_layer_rules(layer, forbidden):
    bad = sorted(f"{m} imports {d}" for m, deps in IMPORTS.items() if _layer(m) == layer
                 for d in deps if _layer(d) in forbidden)
    assert not bad, "\n".join(bad)


def test_only_service_imports_service():
    bad = sorted(f"{m} imports {d}" for m, deps in IMPORTS.items()
                 if _layer(m) not in ("service",) and m != "spidersim.cli"
                 for d in deps if _layer(d) == "service")
    assert not bad, "\n".join(bad)
