"""Where results go and how they are written: confined folders, complete files only.

Rules (issue #12):

- A folder chosen by spidersim (``results/<stem>``) takes its ``<stem>`` from
  :func:`safe_stem`: letters, digits, ``-`` and ``_`` only, so that no text of a diagram
  (``name: ../../x``, ``/abs/path``) can point anywhere else.
- The output folder is created and probed for writing by :func:`prepare_out` before anything
  is computed: a folder that is a file, read-only or cannot be created is a clear error at
  once, not a traceback after the simulation.
- Every file is written under a temporary name in its folder and renamed when complete
  (:func:`write_atomic`, :func:`atomic_path`): a full disk, a crash or an interrupt leaves
  the complete file or none, never a truncated one, and the error names the file.
  A path that exists and is not a regular file (a FIFO, ``/dev/null``, ``/dev/stdout``, a
  terminal) is written *through*, as a shell redirection would: the rename would replace
  the special file by a regular one (as root, ``/dev/null`` itself).
"""
from __future__ import annotations

import contextlib
import os
import re
import stat

from .errors import SpidersimError

_UNSAFE = re.compile(r"[^A-Za-z0-9_-]+")


def safe_stem(*candidates, limit=80):
    """The first candidate reduced to letters, digits, ``-`` and ``_`` that is not empty
    (runs of anything else become one ``_``; leading/trailing ``_``/``-`` dropped; at most
    ``limit`` characters), else ``"diagram"``: a folder or file stem that can never hold a
    separator, ``..`` or an absolute path."""
    for text in candidates:
        if text is None:
            continue
        stem = _UNSAFE.sub("_", str(text)).strip("_-")[:limit]
        if stem:
            return stem
    return "diagram"


def prepare_out(out, what="output folder"):
    """Create ``out`` and check that a file can be written in it; raise SpidersimError.

    Called before compiling or computing, so that an unusable ``--out`` (an existing file, a
    path through a file, a read-only folder, an empty text) is refused at once. A path with
    ``..`` (``x/../y``) is resolved first, so that only the output folder and its missing
    parents are created (``x`` is not). Returns the folder to write into.
    """
    if not str(out).strip():
        raise SpidersimError(f"the {what} must be named, got an empty text")
    if ".." in os.path.normpath(out).split(os.sep) or ".." in str(out).split(os.sep):
        # x/../y: makedirs would create x as well; create the folder the path resolves to
        # (a missing x is skipped, an existing link x followed, as the system would)
        out = os.path.relpath(os.path.realpath(out)) if not os.path.isabs(out) else \
            os.path.realpath(out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise SpidersimError(f"{what} {out} exists and is not a folder; choose another --out")
    try:
        os.makedirs(out, exist_ok=True)
        probe = os.path.join(out, f".spidersim-write-test-{os.getpid()}")
        with open(probe, "w") as fh:
            fh.write("ok")
        os.remove(probe)
    except OSError as exc:
        raise SpidersimError(f"cannot write into the {what} {out}: {exc.strerror or exc}; "
                             f"choose another --out") from None
    return out


def _remove(path):
    try:
        os.remove(path)
    except OSError:
        pass


def _named(exc, path):
    return OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}")


def is_special(path):
    """True when ``path`` exists and is neither a regular file nor a folder (a FIFO, a
    character or block device, a socket): written through, never replaced."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def _open_special(path, binary, kw):
    """Open special file ``path`` for writing; a FIFO that no process reads is an
    :class:`OSError` at once (opened without blocking: ``ENXIO``), not a wait forever."""
    import errno
    import fcntl
    if stat.S_ISFIFO(os.stat(path).st_mode):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
        except OSError as exc:
            if exc.errno == errno.ENXIO:
                raise OSError(exc.errno, "it is a FIFO that no process is reading") from None
            raise
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
        return os.fdopen(fd, "wb" if binary else "w", **kw)
    return open(path, "wb" if binary else "w", **kw)


def write_atomic(path, write, binary=False):
    """``write(fh)`` into a temporary file beside ``path``, then rename it to ``path``.

    On any failure (disk full, folder removed, an interrupt) the temporary is removed; an
    :class:`OSError` is raised again naming ``path``. ``path`` itself is either the complete
    new file or what it was before, never a truncated file. A special file at ``path``
    (:func:`is_special`) is written through instead.
    """
    kw = {} if binary else {"newline": ""}
    if is_special(path):
        try:
            with _open_special(path, binary, kw) as fh:
                write(fh)
        except OSError as exc:
            raise _named(exc, path) from None
        return
    with atomic_path(path) as tmp:
        with open(tmp, "wb" if binary else "w", **kw) as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())


@contextlib.contextmanager
def atomic_path(path):
    """A temporary path beside ``path`` with the same extension (matplotlib chooses the
    format from it) for a writer that takes a file name; renamed to ``path`` when the block
    ends without error, removed otherwise (an OSError names ``path``)::

        with atomic_path(os.path.join(out, "bode.png")) as tmp:
            fig.savefig(tmp)

    A special file at ``path`` (:func:`is_special`) is yielded itself: written through.
    """
    if is_special(path):
        try:
            yield path
        except OSError as exc:
            raise _named(exc, path) from None
        return
    folder, name = os.path.split(path)
    tmp = os.path.join(folder, f".tmp-{os.getpid()}-{name}")
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        _remove(tmp)
        raise _named(exc, path) from None
    except BaseException:
        _remove(tmp)
        raise


def save_figure(fig, path, dpi=110):
    """Write a matplotlib figure to ``path`` atomically (:func:`atomic_path`) and close it,
    also when writing fails; returns ``path``."""
    import matplotlib.pyplot as plt
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        plt.close(fig)
    return path


#: a bare file name in a results folder: letters, digits, ``_ - .``, not starting with a
#: dot or a dash, at most 121 characters (plots' ``file:``, the service's routes, the
#: remote client's downloads)
BARE_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,120}\Z")

#: extensions of the files a run writes (the only ones :func:`remove_stale` removes)
_RESULT_EXT = (".npz", ".csv", ".txt", ".json", ".png", ".svg", ".pdf", ".gif")


def remove_stale(out, listed):
    """Remove from folder ``out`` the files an earlier run listed as its own (``listed``:
    the ``files`` of its ``report.json``): plain file names with a result extension that
    are regular files; nothing else (files the user put there stay). Returns the names
    removed."""
    removed = []
    for name in listed or ():
        if not isinstance(name, str) or os.path.basename(name) != name or \
                name in ("", ".", "..") or not name.lower().endswith(_RESULT_EXT):
            continue
        path = os.path.join(out, name)
        if os.path.isfile(path) and not os.path.islink(path):
            try:
                os.remove(path)
                removed.append(name)
            except OSError:
                pass
    return removed
