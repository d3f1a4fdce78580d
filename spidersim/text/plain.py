"""reST docstrings as plain terminal text (``spidersim blocks TYPE``).

Only what the block docstrings use is handled: inline literals (````x````), roles
(``:math:`x```, ``:func:`~a.b```), directives (``.. math::`` keeps its indented body,
other directive lines are dropped) and ``::`` literal-block markers.
"""
from __future__ import annotations

import re

_ROLE = re.compile(r":[a-z]+:`~?\.?([^`]*)`")
_LITERAL = re.compile(r"``([^`]*)``")
_DIRECTIVE = re.compile(r"^(\s*)\.\.\s+[A-Za-z-]+::.*$")


def plain(text: str) -> str:
    """``text`` with its reST markup removed (see the module docstring)."""
    text = _LITERAL.sub(r"\1", _ROLE.sub(r"\1", text))   # may span a line break
    out = []
    for line in text.splitlines():
        if _DIRECTIVE.match(line):
            continue
        if line.rstrip().endswith("::"):
            line = line.rstrip()[:-1]
        out.append(line)
    return "\n".join(out)


def has_markup(text: str) -> bool:
    """Whether ``text`` still holds reST markup of the kinds :func:`plain` removes."""
    return bool(_ROLE.search(text) or _LITERAL.search(text)
                or any(_DIRECTIVE.match(ln) for ln in text.splitlines()))
