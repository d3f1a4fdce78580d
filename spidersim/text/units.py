"""Units: Modelica notation parsed and compared with pint.

Blocks declare units as text in the notation of the Modelica Standard Library: ``.`` multiplies,
``/`` divides, a trailing integer is a power (``"N.m"``, ``"m/s2"``, ``"kg.m2"``,
``"N.m.s/rad"``, ``"V/(A.s)"``, ``"Ohm"``); ``"1"`` is a dimensionless quantity. Two more forms
declare units that are not fixed by the block:

``"*"`` (:data:`ANY`)
    inherited: the unit of whatever is connected (a Gain's input, a Constant's output).
``"@u"``, ``"@k*@u"``, ``"@u*s"``, ``"@y/@e/s"``
    a product of other units of the same block (``@name`` a port, state or parameter) and of
    fixed units: a Gain's output is ``@k*@u``, an Integrator's output ``@u*s``.

Radians are dimensionless, as in SI: ``rad/s`` equals ``1/s`` and ``Hz``; ``deg`` is a
different unit (its factor to ``rad`` is pi/180), and so is ``mm`` against ``m``. Two units are
the *same* when one converts to the other with factor 1: a connection carries numbers, not
quantities, so only the same unit can flow through it unchanged.
"""
from __future__ import annotations

import functools
import math
import re

import pint

#: an inherited unit: fixed by what is connected
ANY = "*"

_REGISTRY = pint.UnitRegistry(autoconvert_offset_to_baseunit=False)
_TOKEN = re.compile(r"([A-Za-z_][A-Za-z_0-9]*?)(-?\d+)?(?=$|[./*()\s])")
_ALIASES = {"Ohm": "ohm", "degC": "degree_Celsius", "deg": "degree"}
_MAX_TEXT = 200
_MAX_POWER = 12


class UnitError(ValueError):
    """A unit text that cannot be parsed, or two units that do not convert."""


def _to_pint(text):
    out = []
    i = 0
    text = text.strip()
    while i < len(text):
        ch = text[i]
        if ch in "()":
            out.append(ch)
            i += 1
        elif ch in "./*":
            if text[i + 1:i + 2] in ("*", "/", "."):
                raise UnitError(f"cannot read unit '{text}' at '{text[i:i + 10]}': two "
                                f"operators in a row (write m2 for a square, not m**2)")
            out.append("/" if ch == "/" else "*")
            i += 1
        elif ch.isspace():
            i += 1
        elif ch.isdigit():
            # only the "1" of "1/s": powers belong to a name (m2, s-1), never free numbers
            # (no "10**10**10" for the parser to compute)
            if ch != "1" or text[i + 1:i + 2].isdigit():
                raise UnitError(f"cannot read unit '{text}' at '{text[i:i + 10]}': a number "
                                f"may only be the 1 of 1/s; powers follow a name (m2, s-1)")
            out.append("1")
            i += 1
        else:
            m = _TOKEN.match(text, i)
            if m is None:
                raise UnitError(f"cannot read unit '{text}' at '{text[i:i + 10]}'")
            name, power = m.group(1), m.group(2)
            if power and abs(int(power)) > _MAX_POWER:
                raise UnitError(f"unit '{text}': power {power} of '{name}' is beyond "
                                f"{_MAX_POWER}")
            if name not in _ALIASES and name.endswith("Ohm"):     # kOhm, mOhm
                name = name[:-3] + "ohm"
            out.append(_ALIASES.get(name, name) + (f"**{power}" if power else ""))
            i = m.end()
    return "".join(out)


def parse(text: str) -> pint.Unit:
    """The pint unit of a Modelica unit text (``"N.m/rad"`` -> newton * meter / radian).

    Raises :class:`UnitError` for text that is not a unit (unknown names, ``*``, ``@`` rules)
    and for anything that is not a short text (a number, a list, a mapping: checked before
    the cache look-up, which would raise TypeError on an unhashable value).
    """
    if not isinstance(text, str) or not text.strip() or len(text) > _MAX_TEXT:
        shown = text if isinstance(text, str) else (
            "a mapping" if isinstance(text, dict) else "a list" if isinstance(text, list)
            else repr(text))
        raise UnitError(f"a unit must be a short text such as 'N.m' or 'rad/s', got "
                        f"{shown!s:.60}")
    return _parse_text(text)


@functools.lru_cache(maxsize=4096)
def _parse_text(text: str) -> pint.Unit:
    """:func:`parse` of a text, cached."""
    if text.strip() == "1":
        return _REGISTRY.dimensionless
    if "@" in text or text.strip() == ANY:
        raise UnitError(f"'{text}' is a unit rule, not a unit")
    try:
        unit = _REGISTRY.parse_units(_to_pint(text))
    except UnitError:
        raise
    except Exception as exc:  # pint raises several types for malformed text
        raise UnitError(f"unknown unit '{text}' ({exc})") from None
    return unit


def factor(src: pint.Unit, dst: pint.Unit) -> float:
    """The number ``f`` with ``value_dst = f * value_src``; :class:`UnitError` if the
    dimensions differ or a unit has an offset (degC)."""
    if src.dimensionality != dst.dimensionality:
        raise UnitError(f"{text(src)} does not convert to {text(dst)} "
                        f"({src.dimensionality} vs {dst.dimensionality})")
    try:
        return float(_REGISTRY.Quantity(1.0, src).to(dst).magnitude)
    except pint.errors.OffsetUnitCalculusError:
        raise UnitError(f"{text(src)} -> {text(dst)} has an offset; give the value in "
                        f"{text(dst)}") from None


def base(unit: pint.Unit) -> pint.Unit:
    """The coherent SI unit of ``unit`` (``mOhm`` -> kg.m2/(A2.s3), ``deg`` -> ``rad``)."""
    return _REGISTRY.Quantity(1.0, unit).to_base_units().units


def same(a: pint.Unit, b: pint.Unit) -> bool:
    """True when a signal in unit ``a`` can be read as unit ``b`` unchanged (factor 1)."""
    try:
        return math.isclose(factor(a, b), 1.0, rel_tol=1e-12)
    except UnitError:
        return False


def text(unit: pint.Unit) -> str:
    """Modelica text of a pint unit: ``newton * meter / radian`` -> ``"N.m/rad"``."""
    items = sorted(unit._units.items(), key=lambda kv: (kv[1] < 0, list(unit._units).index(kv[0])))
    num, den = [], []
    for name, power in items:
        sym = _REGISTRY.get_symbol(name)
        sym = {"°": "deg", "°C": "degC"}.get(sym, sym).replace("Ω", "Ohm").replace("µ", "u")
        p = abs(power)
        p = int(p) if float(p).is_integer() else p
        (num if power > 0 else den).append(sym + ("" if p == 1 else str(p)))
    if not num and not den:
        return "1"
    top = ".".join(num) if num else "1"
    if not den:
        return top
    return top + "/" + (den[0] if len(den) == 1 else "(" + ".".join(den) + ")")


def rule_terms(rule: str):
    """``(refs, fixed)`` of a unit rule: ``"@y/@e/s"`` -> ``([("y", 1), ("e", -1)], 1/s)``.

    ``refs`` are (name, power) pairs; ``fixed`` the product of the fixed units. A plain unit
    gives no refs; :data:`ANY` gives ``None``.
    """
    rule = rule.strip()
    if rule == ANY:
        return None
    if "@" not in rule:
        return [], parse(rule)
    refs, fixed = [], _REGISTRY.dimensionless
    for k, (op, term) in enumerate(re.findall(r"(^|[*/])\s*([^*/]+)", rule)):
        power = -1 if op == "/" else 1
        term = term.strip()
        if term.startswith("@"):
            name = term[1:]
            if not name.isidentifier():
                raise UnitError(f"unit rule '{rule}': '{term}' is not @name")
            refs.append((name, power))
        else:
            fixed = fixed * parse(term) ** power
    return refs, fixed


DIMENSIONLESS = _REGISTRY.dimensionless
