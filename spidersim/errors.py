"""Exception hierarchy of spidersim.

Every error a user can cause derives from :class:`SpidersimError`. The CLI prints these
without a traceback and exits with status 2. Each error may carry the file and line of the
YAML construct that caused it and the dotted path of the block involved; ``str(err)`` renders
them as ``file:line: block 'path': message``.
"""
from __future__ import annotations

import unicodedata


def printable(text) -> str:
    """``text`` with control and invisible characters shown as escapes (``\\n``, ``\\u200b``),
    so that a hostile name cannot rewrite the terminal or hide in an error message."""
    out = []
    for ch in str(text):
        if ch == "\n" or ch == "\t" or unicodedata.category(ch) in ("Cc", "Cf", "Zl", "Zp"):
            out.append(ch.encode("unicode_escape").decode("ascii"))
        else:
            out.append(ch)
    return "".join(out)


def non_ascii(text):
    """Where ``text`` leaves ASCII, for a message: ``non-ASCII character '𝟏' (U+1D7CF
    MATHEMATICAL BOLD DIGIT ONE) at character 5``; None for an ASCII text.

    Names, ports and indices are ASCII: Python's ``int`` and a regular expression's ``\\d``
    read other scripts' digits (Arabic-Indic ``١``, bold ``𝟏``) as 1, and a look-alike
    letter would be taken for another name (:data:`ASCII_RULE` says so).
    """
    for pos, ch in enumerate(str(text)):
        if ord(ch) > 127:
            return (f"non-ASCII character '{printable(ch)}' (U+{ord(ch):04X} "
                    f"{unicodedata.name(ch, 'unnamed')}) at character {pos + 1}")
    return None


#: why :func:`non_ascii` characters are refused, for the end of a message
ASCII_RULE = ("names and indices are ASCII (a look-alike digit or letter would be read as "
              "the one it resembles)")


def described(v) -> str:
    """What a Python argument of the wrong type is, for a message: ``None``, ``the boolean
    True``, ``the string '1'``, ``a list of 2``, ``an array of shape (1,)``, ``a mapping``,
    or its short repr with its type (``5 (int)``)."""
    import numpy as np
    if v is None:
        return "None"
    if isinstance(v, (bool, np.bool_)):
        return f"the boolean {bool(v)!r}"
    if isinstance(v, str):
        return f"the string {printable(repr(v)[:60])}"
    if isinstance(v, (bytes, bytearray)):
        return f"the bytes {repr(bytes(v))[:60]}"
    if isinstance(v, (list, tuple, set, frozenset)):
        kind = {list: "list", tuple: "tuple", set: "set", frozenset: "set"}.get(type(v),
                                                                             "sequence")
        return f"a {kind} of {len(v)}" + (f" {printable(repr(v)[:60])}" if v else "")
    if isinstance(v, dict):
        return "a mapping"
    if isinstance(v, np.ndarray):
        return f"an array of shape {v.shape}"
    return f"{printable(repr(v)[:60])} ({type(v).__name__})"


class SpidersimError(Exception):
    """Base class of every error reported to users.

    Parameters
    ----------
    message : str
        What was expected and what was found, with advice where there is some.
    file : str, optional
        YAML file the problem comes from.
    line : int, optional
        1-based line in ``file``.
    block : str, optional
        Dotted path of the block instance (``j3.motor``).
    """

    exit_code = 2
    #: the Result computed up to a failure during a run (None otherwise)
    partial = None

    def __init__(self, message, file=None, line=None, block=None):
        super().__init__(message)
        self.message = message
        self.file = file
        self.line = line
        self.block = block

    def __str__(self):
        where = ""
        if self.file:
            where = f"{self.file}:{self.line}: " if self.line else f"{self.file}: "
        who = f"block '{self.block}': " if self.block else ""
        # a multi-line message keeps its line breaks; names inside it are escaped where they
        # are formatted, and the location parts are escaped here
        return printable(f"{where}{who}") + "\n".join(printable(m)
                                                   for m in str(self.message).split("\n"))


class DiagramError(SpidersimError):
    """Malformed diagram: YAML syntax, unknown sections, bad subsystem files."""


class BlockTypeError(DiagramError):
    """Unknown block type or malformed block entry."""


class ParameterError(SpidersimError):
    """Unknown, missing, out-of-bounds or mis-shaped parameter, bad expression."""


class ResultError(SpidersimError):
    """A result that cannot be read: ``Result.load`` of a missing folder, of a file, of a
    folder without ``result.npz`` or of a damaged one."""


class SignalError(SpidersimError, KeyError):
    """A signal a result does not hold, or a name that is not a text (``r[5]``,
    ``r.plot(["nope"])``). A :class:`KeyError` too, as a missing mapping key is."""


class WiringError(SpidersimError):
    """Unknown port, size mismatch, two sources into one input, unconnected input."""


class AlgebraicLoopError(SpidersimError):
    """An algebraic loop that is not supported or could not be solved."""


class IntegrationError(SpidersimError):
    """The integration failed (non-finite value, step size too small, ...).

    ``partial`` holds the :class:`~spidersim.solver.result.Result` computed up to the failure.
    """

    def __init__(self, message, partial=None, **kw):
        super().__init__(message, **kw)
        self.partial = partial


class RenamedParameterWarning(FutureWarning):
    """A parameter given under its old name (accepted for one release); the message says
    where and what the new name is. The CLI prints it as ``spidersim: warning: ...``."""


class SweepWarning(UserWarning):
    """A sweep whose grid does not vary what it seems to (a varied parameter that no run
    depends on). The CLI prints it as ``spidersim: warning: ...``."""


class LinearizationWarning(UserWarning):
    """A linearization made with a documented simplification (a quantizer taken as its
    unquantized gain). The CLI prints it as ``spidersim: note: ...``."""
