"""Reading YAML with line numbers, within bounds.

The loader is PyYAML's ``SafeLoader`` (the loader behind ``yaml.safe_load``: plain data only,
no Python objects) extended to remember where each mapping key stands, so that errors can say
``file:line``. Mappings come back as :class:`LineDict`.

Bounds (:mod:`spidersim.text.limits`): file size, UTF-8 validity (the byte offset of the first
bad byte is reported), nesting depth and item counts while composing, alias references, and
the number of nodes *after* alias expansion (computed on the composed node graph, memoised
per node, so an alias bomb of 10^9 elements is refused before anything is built).
"""
from __future__ import annotations

import contextlib
import contextvars
import math
import os
import re
import stat

import yaml

from ..errors import DiagramError
from . import limits


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
    """SafeLoader that refuses deep nesting and too many aliases while composing."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self._aliases = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > limits.MAX_ALIASES:
                raise _Limit(f"more than {limits.MAX_ALIASES} alias references (*name)",
                             self.peek_event().start_mark)
        self._depth += 1
        if self._depth > limits.MAX_DEPTH:
            raise _Limit(f"lists and mappings nested deeper than {limits.MAX_DEPTH} levels",
                         self.peek_event().start_mark)
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


class _Limit(Exception):
    def __init__(self, message, mark):
        super().__init__(message)
        self.message = message
        self.line = mark.line + 1 if mark is not None else None


def _expanded_size(root):
    """Nodes of ``root`` with every alias expanded, and the check of per-node bounds.

    Iterative and memoised per node object, so shared (aliased) subtrees cost once to
    measure however often they are referenced.
    """
    memo = {}
    open_ = set()                 # nodes whose children are being measured
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if key in memo:
            continue
        if not done and key in open_:
            # reached again from inside itself: every later entry on the stack is one of its
            # descendants (those pushed before it are measured after it is done)
            raise DiagramError("an alias (*name) refers to a list or mapping that contains "
                               "it: a recursive structure, which no diagram value can be",
                               line=node.start_mark.line + 1)
        if isinstance(node, yaml.ScalarNode):
            if len(node.value) > limits.MAX_STRING:
                raise _Limit(f"a text longer than {limits.MAX_STRING} characters",
                             node.start_mark)
            _check_scalar(node)
            memo[key] = 1
            continue
        children = ([c for kv in node.value for c in kv]
                    if isinstance(node, yaml.MappingNode) else list(node.value))
        if len(node.value) > limits.MAX_ITEMS:
            raise _Limit(f"a list or mapping with more than {limits.MAX_ITEMS} entries "
                         f"({len(node.value)})", node.start_mark)
        if not done:
            open_.add(key)
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in memo)
            continue
        total = 1
        for c in children:
            total += memo[id(c)]
            if total > limits.MAX_NODES:
                raise _Limit(f"more than {limits.MAX_NODES} values once aliases are expanded "
                             f"(an alias bomb?)", node.start_mark)
        memo[key] = total
        open_.discard(key)
    return memo.get(id(root), 0)


_INT_TAG = "tag:yaml.org,2002:int"
_FLOAT_TAG = "tag:yaml.org,2002:float"
_TIMESTAMP_TAG = "tag:yaml.org,2002:timestamp"
#: digits of the longest integer read (Python refuses to convert more than 4300)
MAX_INT_DIGITS = 100
_LEADING_ZERO = re.compile(r"^[-+]?0[0-9_]")


_SURROGATE = re.compile("[\ud800-\udfff]")


def lone_surrogate(text: str):
    """The first lone surrogate (U+D800..U+DFFF) in ``text``, or None: not a character (a
    ``"\\ud800"`` escape in YAML or JSON, a byte that is not UTF-8 on the command line); it
    cannot be printed, stored or written to a file. Used by the loader, the CLI's arguments
    and the service's requests."""
    m = _SURROGATE.search(text)
    return m.group() if m else None


def _check_scalar(node):
    """Refuse a lone surrogate (``"\\ud800"`` in a quoted text: not a character, it cannot
    be printed or written to a file) and a plain scalar :func:`number_problem` refuses;
    each with its line."""
    text = node.value
    line = node.start_mark.line + 1
    ch = lone_surrogate(text)
    if ch:
        raise DiagramError(f"a lone surrogate \\u{ord(ch):04x} (an escape in a quoted "
                           f"text) is not a character", line=line)
    if node.style is not None:
        return
    problem = number_problem(text, node.tag)
    if problem:
        raise DiagramError(problem, line=line)


def number_problem(text: str, tag: str | None = None):
    """Why the plain (unquoted) YAML scalar ``text`` is refused, or None.

    Refused: the YAML 1.1 number forms a reader does not expect (``010``: octal 8,
    ``1:30``: base 60, 90), integers too long to convert, a float beyond the float range
    (``1.0e+400``, read as infinity; ``.inf`` is the spelling of one) and a date that is none
    (``2020-13-01``, which PyYAML fails on with a bare ValueError). The rule of diagram
    files, and of values on the command line (``--set``, ``--vary``).

    Parameters
    ----------
    text : str
    tag : str, optional
        The tag YAML resolves ``text`` to; None: resolved here.
    """
    if tag is None:
        tag = _Loader.resolve(_Loader, yaml.ScalarNode, text, (True, False))
    if tag == _TIMESTAMP_TAG:
        return _date_problem(text)
    if tag not in (_INT_TAG, _FLOAT_TAG):
        return None
    if ":" in text:
        return (f"'{text}' is a base-60 number in YAML 1.1 (1:30 means 90): write the "
                f"number, or quote it if it is a text")
    if tag == _INT_TAG:
        return _integer_problem(text)
    if _overflows(text):
        return (f"the number '{text}' is beyond the float range (1.8e308) and would be read "
                f"as infinity: write .inf if an infinity is meant")
    return None


def _integer_problem(text):
    """Why the YAML integer ``text`` is refused (a leading zero, too many digits), or
    None."""
    if _LEADING_ZERO.match(text):
        return (f"'{text}' has a leading zero, which YAML 1.1 reads as an octal number "
                f"('010' is 8): write it without the zero")
    digits = len(text.replace("_", ""))
    if digits > MAX_INT_DIGITS:
        return (f"an integer of {digits} characters: no value of a diagram needs more than "
                f"{MAX_INT_DIGITS}")
    return None


def _date_problem(text):
    """Why ``text``, resolved as a YAML date, is refused (``2020-13-01`` is none), or
    None."""
    try:
        yaml.constructor.SafeConstructor().construct_yaml_timestamp(
            yaml.ScalarNode(_TIMESTAMP_TAG, text))
    except ValueError as exc:
        return (f"'{text}' is written as a YAML date but is none ({exc}): quote it if it is "
                f"a text")
    return None


def _overflows(text):
    """Whether the YAML float ``text`` is a finite number too large for a float
    (``1.0e+400``); ``.inf`` is the explicit spelling of infinity and stays (``.nan`` is
    refused where it is used)."""
    body = text.replace("_", "").lstrip("+-").lower()
    return body not in (".inf", ".nan") and math.isinf(float(body))


def command_line_value(text: str, what: str):
    """A value given on the command line (``--set path=VALUE``), read as the loader reads a
    diagram file's values: plain YAML data within the same bounds, a number form a file
    refuses refused here too (:func:`number_problem`, e.g. ``010``; a DiagramError
    starting with ``what``); a text that is not YAML (``a: b: c``) or a tag the safe
    loader does not build is kept as the text."""
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node)
        return loader.construct_document(node)
    except (_Limit, DiagramError) as exc:
        raise DiagramError(f"{what}: {exc.message}") from None
    except yaml.YAMLError:
        return text
    finally:
        loader.dispose()


def _key_not_a_name(key, knode):
    """The message for a mapping key that YAML read as a number, a boolean or null: every
    key of a diagram (block names, parameters, settings, signals) is a name."""
    written = knode.value if isinstance(knode, yaml.ScalarNode) else key
    what = ("a boolean (YAML reads yes/no/on/off/true/false so)" if isinstance(key, bool)
            else "empty (null)" if key is None else "an integer" if isinstance(key, int)
            else "a number" if isinstance(key, float) else f"a {type(key).__name__}")
    return (f"mapping key '{written}' is {what}, not a name: keys (block names, parameters, "
            f"settings) are identifiers; quote it ('{written}') if the text is meant")


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
        if not isinstance(key, str):
            raise DiagramError(_key_not_a_name(key, knode), line=knode.start_mark.line + 1)
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


def decode(raw: bytes, file: str) -> str:
    """UTF-8 text of a file's bytes within :data:`limits.MAX_FILE_BYTES`, or a DiagramError
    naming the file and the offset of the first byte that is not UTF-8."""
    if len(raw) > limits.MAX_FILE_BYTES:
        raise DiagramError(f"file is {len(raw)} bytes, more than the limit of "
                           f"{limits.MAX_FILE_BYTES} bytes for a diagram file", file=file)
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise DiagramError(f"not UTF-8 text: byte 0x{raw[exc.start]:02x} at byte offset "
                           f"{exc.start}; save the file as UTF-8", file=file,
                           line=line) from None


#: folders whose files may be read while a model is prepared for someone else (None: any)
_ROOTS = contextvars.ContextVar("spidersim_file_roots", default=None)


@contextlib.contextmanager
def files_only_under(roots):
    """Within the block, :func:`read_file` and :func:`readable` accept only files inside
    ``roots`` (after resolving links): the service prepares a request's model so, and a
    parameter of the request that names a file of the server (``Arm.model:
    /etc/passwd``) is refused without the file being opened or its existence told."""
    token = _ROOTS.set(tuple(os.path.realpath(r) for r in roots))
    try:
        yield
    finally:
        _ROOTS.reset(token)


def readable(path: str) -> bool:
    """Whether ``path`` may be read here (always, outside :func:`files_only_under`)."""
    roots = _ROOTS.get()
    if roots is None:
        return True
    real = os.path.realpath(path)
    return any(real == r or real.startswith(r.rstrip(os.sep) + os.sep) for r in roots)


def refuse_unreadable(path: str, what: str = "file"):
    """:class:`DiagramError` unless :func:`readable`; names the path as given only."""
    if not readable(path):
        raise DiagramError(f"{what} '{path}' is not among the files this server's models may "
                           f"read (a request cannot name files of the server)")


_SPECIAL = ((stat.S_ISFIFO, "a FIFO, a named pipe"), (stat.S_ISCHR, "a character device"),
            (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _mode_problem(mode):
    """None for a regular file, else what the file is instead, in words."""
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISDIR(mode):
        return "is a folder, not a file"
    kind = next((k for test, k in _SPECIAL if test(mode)), "a special file")
    return f"is not a regular file ({kind})"


def file_problem(path: str):
    """Why ``path`` cannot be read as a diagram file: ``"not found"``, ``"is a folder, not
    a file"``, ``"is not a regular file (a character device)"`` (``/dev/zero``,
    ``/dev/null``, a FIFO: never opened, so a FIFO cannot block), ``"cannot be read
    (...)"``; None for a regular file (a link to one included)."""
    try:
        st = os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return "not found"
    except (OSError, ValueError) as exc:          # ValueError: a NUL in the path
        return f"cannot be read ({getattr(exc, 'strerror', None) or exc})"
    return _mode_problem(st.st_mode)


def read_file(path: str):
    """Read and parse a YAML file within bounds (see :func:`load_text`); a file outside
    :func:`files_only_under` is refused unopened. Opened without blocking and checked to
    be a regular file before a byte is read (a FIFO put in its place after a check by
    name would otherwise wait for a writer forever)."""
    refuse_unreadable(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as fh:
            problem = _mode_problem(os.fstat(fd).st_mode)
            if problem:
                raise DiagramError(f"file {problem}", file=path)
            raw = fh.read(limits.MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise DiagramError(f"cannot read file: {exc.strerror}", file=path) from None
    return load_text(decode(raw, path), path)


def load_text(text: str, file: str = "<string>"):
    """Parse YAML text; syntax errors and exceeded limits become :class:`DiagramError` with
    file and line."""
    if len(text) > limits.MAX_FILE_BYTES:
        raise DiagramError(f"text of {len(text)} characters, more than the limit of "
                           f"{limits.MAX_FILE_BYTES}", file=file)
    if "\x00" in text:
        raise DiagramError(f"NUL character at offset {text.index(chr(0))}: not a text "
                           f"file", file=file, line=text[:text.index(chr(0))].count("\n") + 1)
    loader = None
    try:
        loader = _Loader(text)  # SafeLoader subclass: plain data only
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node)
        data = loader.construct_document(node)
    except _Limit as exc:
        raise DiagramError(f"{exc.message}: over the limit for a diagram file (see "
                           f"'Limits' in the README)", file=file, line=exc.line) from None
    except RecursionError:
        raise DiagramError("nesting too deep to read", file=file) from None
    except DiagramError as exc:
        exc.file = file
        raise
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else None
        msg = " ".join(str(m) for m in (exc.context, exc.problem) if m)
        raise DiagramError(f"YAML syntax error: {msg}", file=file, line=line) from None
    except yaml.reader.ReaderError as exc:
        raise DiagramError(_unreadable_character(text, exc), file=file,
                           line=text[:exc.position].count("\n") + 1) from None
    except yaml.YAMLError as exc:
        raise DiagramError(f"YAML error: {exc}", file=file) from None
    finally:
        if loader is not None:
            loader.dispose()
    return data


def _unreadable_character(text, exc):
    """The message for a character YAML does not allow (a control character, a lone
    surrogate, U+FFFE/U+FFFF), anywhere in the file, comments included."""
    col = exc.position - (text.rfind("\n", 0, exc.position) + 1) + 1
    ch = exc.character
    code = ord(ch) if isinstance(ch, str) else int(ch)
    return (f"character U+{code:04X} at column {col} is not allowed in a YAML file (control "
            f"characters other than tab and line ends, lone surrogates and U+FFFE/U+FFFF, "
            f"in comments too); remove it")


def found(v):
    """What a value of the wrong type is, for a message: ``a list``, ``a mapping``, ``the
    boolean True``, ``nothing (an empty entry)`` or its short repr."""
    if isinstance(v, bool):
        return f"the boolean {v!r}"
    if isinstance(v, (list, tuple)):
        return "a list"
    if isinstance(v, dict):
        return "a mapping"
    if v is None:
        return "nothing (an empty entry)"
    return repr(v)[:60]
