"""Reading YAML with line numbers.

The loader is PyYAML's ``SafeLoader`` (the loader behind ``yaml.safe_load``: plain data only,
no Python objects) extended to remember where each mapping key stands, so that errors can say
``file:line``. Mappings come back as :class:`LineDict`.
"""
from __future__ import annotations

import yaml

from ..errors import DiagramError


class LineDict(dict):
    """A dict that knows the 1-based line of each key (``d.line_of(key)``)."""

    line = None

    def line_of(self, key=None):
        if key is not None and key in getattr(self, "lines", {}):
            return self.lines[key]
        return self.line


class LineList(list):
    line = None
    lines: list


class _Loader(yaml.SafeLoader):
    pass


def _construct_mapping(loader, node):
    loader.flatten_mapping(node)
    d = LineDict()
    d.line = node.start_mark.line + 1
    d.lines = {}
    for knode, vnode in node.value:
        key = loader.construct_object(knode, deep=True)
        try:
            hash(key)
        except TypeError:
            raise DiagramError(f"mapping key {key!r} is not a scalar",
                               line=knode.start_mark.line + 1) from None
        if key in d:
            raise DiagramError(f"duplicate key '{key}' (first on line {d.lines[key]})",
                               line=knode.start_mark.line + 1)
        d[key] = loader.construct_object(vnode, deep=True)
        d.lines[key] = knode.start_mark.line + 1
    return d


def _construct_sequence(loader, node):
    out = LineList(loader.construct_object(c, deep=True) for c in node.value)
    out.line = node.start_mark.line + 1
    out.lines = [c.start_mark.line + 1 for c in node.value]
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _construct_sequence)


def load_text(text: str, file: str = "<string>"):
    """Parse YAML text; syntax errors become :class:`DiagramError` with file and line."""
    try:
        data = yaml.load(text, Loader=_Loader)  # SafeLoader subclass: plain data only
    except DiagramError as exc:
        exc.file = file
        raise
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else None
        msg = " ".join(str(m) for m in (exc.context, exc.problem) if m)
        raise DiagramError(f"YAML syntax error: {msg}", file=file, line=line) from None
    except yaml.YAMLError as exc:
        raise DiagramError(f"YAML error: {exc}", file=file) from None
    return data
