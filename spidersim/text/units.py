"""Units: Modelica notation parsed and compared with pint.

Blocks declare units as text in the notation of the Modelica Standard Library: ``.`` multiplies,
``/`` divides, a trailing integer is a power (``"N.m"``, ``"m/s2"``, ``"kg.m2"``,
``"N.m.s/rad"``, ``"V/(A.s)"``, ``"Ohm"``, ``"rev/min"``); ``"1"`` is a dimensionless quantity.
Two more forms declare units that are not fixed by the block:

``"*"`` (:data:`ANY`)
    inherited: the unit of whatever is connected (a Gain's input, a Constant's output).
``"@u"``, ``"@k*@u"``, ``"@u*s"``, ``"@y/@e/s"``
    a product of other units of the same block (``@name`` a port, state or parameter) and of
    fixed units: a Gain's output is ``@k*@u``, an Integrator's output ``@u*s``.

A unit text is a unit, never a number or a formula: the only number is the ``1`` of ``1/s``
(``"1e-3 m"``, ``"1e3"``, ``"2.m"`` are refused; write the number in the value), two names
side by side are refused (``"m s"`` would be pint's millisecond, ``"N m"`` a product: write
``m.s``, ``N.m``), and so are names pint gives to what is not a unit here: its physical and
mathematical constants (``e`` the elementary charge, ``c``, ``k``, ``pi``, ...), logarithmic
units (``dB``, ``Np``, ``octave``, ``decade``: a level is not a factor), information units
(``B`` is pint's byte, not the bel) and the textile ``Nm`` (write ``N.m``).

Radians are dimensionless, as in SI: ``rad/s`` equals ``1/s``; ``deg`` is a different unit
(its factor to ``rad`` is pi/180), and so is ``mm`` against ``m``. ``Hz`` counts cycles per
second: between a unit that holds ``Hz`` and one that holds an angle (``rad``, ``deg``,
``rev``, ``rpm``, ...) the conversion goes through 1 Hz = 1 rev/s = 2 pi rad/s (60 rpm =
1 Hz, ``N.m/Hz`` -> ``N.m.s/rad`` is 1/(2 pi)); without an angle on either side ``Hz`` is
``1/s`` (factor 1). See :func:`factor`. Two units are the *same* when one converts to the
other with factor 1: a connection carries numbers, not quantities, so only the same unit can
flow through it unchanged (``rad/s`` and ``Hz`` are not the same; ``Hz`` and ``1/s`` are).

``degC`` and ``degF`` are temperatures on scales with an offset: they convert only to an
absolute temperature (a lone ``K``, ``degC``, ``degF``, ``degR``; 20 degC = 293.15 K), see
:func:`affine`; in a product (``W/degC``) or anywhere a factor is needed they are refused.
A temperature difference is written in ``K`` (or ``delta_degC``).
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
_ALIASES = {"Ohm": "ohm", "degC": "degree_Celsius", "deg": "degree", "rev": "revolution"}
_MAX_TEXT = 200
_MAX_POWER = 12

#: pint's physical and mathematical constants (its constants_en.txt, canonical names but the
#: standard atmosphere, a unit of pressure): parsed as units, they would scale a value
#: silently (``1e3`` read as e**3, e the elementary charge)
_CONSTANTS = frozenset("""
    pi tansec ln10 wien_x wien_u eulers_number speed_of_light planck_constant elementary_charge
    avogadro_number boltzmann_constant standard_gravity conventional_josephson_constant
    conventional_von_klitzing_constant conventional_water_density conventional_mercury_density
    zeta dirac_constant avogadro_constant molar_gas_constant faraday_constant
    conductance_quantum magnetic_flux_quantum josephson_constant von_klitzing_constant
    stefan_boltzmann_constant first_radiation_constant second_radiation_constant
    wien_wavelength_displacement_law_constant wien_frequency_displacement_law_constant
    newtonian_constant_of_gravitation rydberg_constant electron_g_factor atomic_mass_constant
    electron_mass proton_mass neutron_mass x_unit_Cu x_unit_Mo angstrom_star water_density_4C
    water_density_60F mercury_density_0C mercury_density_32F mercury_density_60F
    fine_structure_constant vacuum_permeability vacuum_permittivity impedance_of_free_space
    coulomb_constant classical_electron_radius thomson_cross_section""".split())
#: other pint names refused, with the reason
_REFUSED = {
    "bit": "an information unit", "byte": "an information unit ('B' is pint's byte, not "
    "the bel)", "baud": "an information rate",
    "number_meter": "pint's textile yarn count ('Nm' is not N.m: write N.m for newton "
    "metre)", "number_english": "pint's textile yarn count",
}


class UnitError(ValueError):
    """A unit text that cannot be parsed, or two units that do not convert."""


def _to_pint(text):
    out = []
    i = 0
    text = text.strip()
    operand = False         # the last item read was a name, a 1 or a ')'
    while i < len(text):
        ch = text[i]
        if ch in "()":
            if ch == "(" and operand:
                raise UnitError(f"cannot read unit '{text}' at '{text[i:i + 10]}': write a "
                                f"product with a dot (N.(m/s)), not side by side")
            out.append(ch)
            operand = ch == ")"
            i += 1
        elif ch in "./*":
            if text[i + 1:i + 2] in ("*", "/", "."):
                raise UnitError(f"cannot read unit '{text}' at '{text[i:i + 10]}': two "
                                f"operators in a row (write m2 for a square, not m**2)")
            out.append("/" if ch == "/" else "*")
            operand = False
            i += 1
        elif ch.isspace():
            i += 1
        elif ch.isdigit():
            # only the "1" of "1/s": powers belong to a name (m2, s-1), never free numbers
            # (no "10**10**10" for the parser to compute, no "1e-3 m" read as 1/e**3 m)
            after = text[i + 1:].lstrip()[:1]
            if ch != "1" or operand or after not in ("/", ")", ""):
                raise UnitError(f"cannot read unit '{text}' at '{text[i:i + 10]}': a number "
                                f"may only be the 1 of 1/s; powers follow a name (m2, s-1); "
                                f"write a scale in the value ({{value: 5e-3, unit: m}}) or "
                                f"as a prefix (mm)")
            out.append("1")
            operand = True
            i += 1
        else:
            m = _TOKEN.match(text, i)
            if m is None:
                raise UnitError(f"cannot read unit '{text}' at '{text[i:i + 10]}'")
            if operand:
                raise UnitError(f"cannot read unit '{text}' at '{text[i:i + 10]}': two names "
                                f"side by side; write a product with a dot (N.m, m.s: "
                                f"'m s' would be read as ms, the millisecond)")
            name, power = m.group(1), m.group(2)
            if power and abs(int(power)) > _MAX_POWER:
                raise UnitError(f"unit '{text}': power {power} of '{name}' is beyond "
                                f"{_MAX_POWER}")
            if name not in _ALIASES and name.endswith("Ohm"):     # kOhm, mOhm
                name = name[:-3] + "ohm"
            name = _ALIASES.get(name, name)
            _check_name(text, m.group(1), name)
            out.append(name + (f"**{power}" if power else ""))
            operand = True
            i = m.end()
    return "".join(out)


def _check_name(text, written, name):
    """A :class:`UnitError` for a name pint reads as something that is not a unit here: a
    constant, a logarithmic unit, an information unit (see the module doc). Unknown names
    are left to pint (which names them in its error)."""
    try:
        found = _REGISTRY.parse_unit_name(name)
    except Exception:       # pint raises several types for malformed names
        return
    for _prefix, root, _suffix in found[:1]:      # pint's reading ('dB': decibel, not dbyte)
        why = None
        if root in _CONSTANTS:
            why = (f"is pint's constant {root}, not a unit; write numbers in the value "
                   f"({{value: 5e-3, unit: m}}), not in the unit")
        elif root in _REFUSED:
            why = f"is {_REFUSED[root]}, not a unit of this simulator"
        elif getattr(_converter(root), "is_logarithmic", False):
            why = (f"is a logarithmic unit ({root}): a level, not a factor (20 dB is an "
                   f"amplitude ratio of 10, a power ratio of 100); give the ratio as a plain "
                   f"number")
        if why is not None:
            raise UnitError(f"unit '{text}': '{written}' {why}")


def _converter(root):
    """pint's converter of unit ``root`` (scale, offset or logarithmic), None if unknown."""
    definition = _REGISTRY._units.get(root)
    return getattr(definition, "converter", None)


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
    """The number ``f`` with ``value_dst = f * value_src``.

    pint's factor (radians dimensionless, ``Hz`` = ``1/s``), except between a unit that holds
    ``Hz`` and one that holds an angle: there ``Hz`` is a cycle per second, 1 Hz = 1 rev/s =
    2 pi rad/s. With ``a`` the power of ``rad`` in a unit's root units (``rpm``: rad/s, 1;
    ``deg``: 1; ``Hz``: 0) and ``h`` its power of ``Hz`` (prefixed or not), when the angles
    do not balance (``a_src != a_dst``) but do once ``Hz`` is read as ``rev/s``
    (``a_src + h_src == a_dst + h_dst``)::

        f = f_pint * (2 pi) ** (h_src - h_dst)

    e.g. ``rad/s`` -> ``Hz``: 1/(2 pi); ``rpm`` -> ``Hz``: (2 pi/60)/(2 pi) = 1/60;
    ``Hz`` -> ``rad/s``: 2 pi; ``N.m/Hz`` -> ``N.m.s/rad``: 1/(2 pi); ``Hz`` -> ``1/s``
    and ``rad/s`` -> ``1/s`` (no Hz, or no angle): 1.

    Raises :class:`UnitError` if the dimensions differ or a unit has an offset (``degC``;
    identical units excepted): such a value needs :func:`affine`.
    """
    if src.dimensionality != dst.dimensionality:
        raise UnitError(f"{text(src)} does not convert to {text(dst)} "
                        f"({src.dimensionality} vs {dst.dimensionality})")
    if _offset_names(src) or _offset_names(dst):
        if src == dst:
            return 1.0
        raise UnitError(f"{text(src)} -> {text(dst)} has an offset; give the value in "
                        f"{text(dst)}")
    f = float(_REGISTRY.Quantity(1.0, src).to(dst).magnitude)
    a_src, h_src = _angle_and_hertz(src)
    a_dst, h_dst = _angle_and_hertz(dst)
    if not _close(a_src, a_dst) and _close(a_src + h_src, a_dst + h_dst):
        f *= (2.0 * math.pi) ** (h_src - h_dst)
    return f


def _close(a, b):
    return abs(a - b) < 1e-9


@functools.lru_cache(maxsize=4096)
def _angle_and_hertz(unit):
    """``(a, h)``: the power of ``rad`` in the root units of ``unit`` and its power of
    ``Hz`` (``kHz`` included)."""
    a = float(_REGISTRY.get_root_units(unit)[1]._units.get("radian", 0))
    h = float(sum(p for name, p in unit._units.items() if _root_name(name) == "hertz"))
    return a, h


@functools.lru_cache(maxsize=1024)
def _root_name(name):
    """pint's unit name without its prefix (``kilohertz`` -> ``hertz``)."""
    found = _REGISTRY.parse_unit_name(name)
    return found[0][1] if found else name


def _offset_names(unit):
    """The names in ``unit`` of scales with an offset (``degree_Celsius``,
    ``degree_Fahrenheit``, ``degree_Reaumur``)."""
    return [n for n in unit._units
            if getattr(_converter(_root_name(n)), "offset", 0.0) != 0.0]


def _absolute_temperature(unit):
    """True for a lone temperature on an absolute scale or a scale with an offset (``K``,
    ``degC``, ``degF``, ``degR``), power 1; not a difference (``delta_degC``)."""
    items = list(unit._units.items())
    return (len(items) == 1 and items[0][1] == 1 and not items[0][0].startswith("delta_")
            and unit.dimensionality == _REGISTRY.kelvin.dimensionality)


def affine(src: pint.Unit, dst: pint.Unit) -> tuple[float, float]:
    """``(a, b)`` with ``value_dst = a * value_src + b``.

    ``b`` is 0 and ``a`` the :func:`factor` unless a unit has an offset. A temperature on a
    scale with an offset converts to an absolute temperature: both units a lone temperature
    (``K``, ``degC``, ``degF``, ``degR``), ``a`` the ratio of the degrees and ``b`` the image
    of 0 (``degC`` -> ``K``: a = 1, b = 273.15; ``degF`` -> ``K``: a = 5/9,
    b = 255.372...; 20 degC = 293.15 K, 68 degF = 293.15 K). Anything else with an offset
    (``W/degC``, ``degC`` -> ``delta_degC``, ``degC2``) is a :class:`UnitError`: a degree
    Celsius in a product or a difference is a kelvin, and is written ``K``.
    """
    if not (_offset_names(src) or _offset_names(dst)):
        return factor(src, dst), 0.0
    if src.dimensionality != dst.dimensionality:
        factor(src, dst)                    # the dimension error
    if not (_absolute_temperature(src) and _absolute_temperature(dst)):
        scale = text(src) if _offset_names(src) else text(dst)
        raise UnitError(f"{text(src)} -> {text(dst)}: {scale} is a temperature scale with an "
                        f"offset; it converts only to and from a temperature (K); write a "
                        f"temperature difference, or a unit such as W/K, in K")
    b = float(_REGISTRY.Quantity(0.0, src).to(dst).magnitude)
    a = float(_REGISTRY.get_root_units(src)[0] / _REGISTRY.get_root_units(dst)[0])
    return a, b


def check_no_offset(unit: pint.Unit, why: str) -> None:
    """A :class:`UnitError` if ``unit`` has an offset (``degC``) in a place that keeps the
    unit without converting the value (``why`` says where)."""
    if _offset_names(unit):
        raise UnitError(f"{text(unit)} is a temperature scale with an offset, which {why} "
                        f"cannot carry; give the value in K (a temperature difference in K "
                        f"or delta_degC)")


def terms(unit: pint.Unit) -> list:
    """The factors of ``unit`` as ``(single unit, power)`` pairs: ``N.m/deg`` ->
    ``[(N, 1), (m, 1), (deg, -1)]``."""
    return [(_REGISTRY.Unit(name), power) for name, power in unit._units.items()]


def base(unit: pint.Unit) -> pint.Unit:
    """The coherent SI unit of ``unit`` (``mOhm`` -> kg.m2/(A2.s3), ``deg`` -> ``rad``)."""
    return _REGISTRY.Quantity(1.0, unit).to_base_units().units


def same(a: pint.Unit, b: pint.Unit) -> bool:
    """True when a signal in unit ``a`` can be read as unit ``b`` unchanged (factor 1).

    The unit checks of connections and block rules use it: ``rad/s`` into ``Hz`` is a
    mismatch (factor 1/(2 pi)), ``Hz`` into ``1/s`` and ``rad/s`` into ``1/s`` are not (SI).
    The relation is not transitive through ``1/s`` (``Hz`` ~ ``1/s`` ~ ``rad/s``): unit
    inference compares a new unit with every unit bound to a class of ports."""
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
        sym = sym.replace("Δ", "delta_")
        sym = re.sub("°(C|F|R|Re)?", lambda m: "deg" + (m.group(1) or ""), sym)
        sym = sym.replace("Ω", "Ohm").replace("µ", "u")
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
