"""Python client of the spidersim service (``spidersim serve``)::

    from spidersim.remote import Client
    c = Client("http://127.0.0.1:8050", token)          # token: spidersim serve --add-user
    c.models()                                           # the library
    job = c.submit("servo", parameters={"motor.R": 1.2}, t_end=0.5)
    c.wait(job)                                          # final status (done, failed, ...)
    r = c.result(job)                                    # a spidersim.Result, as local runs
    r["motor.w"], r.stats

Errors of the service come back as :class:`RemoteError` (a
:class:`~spidersim.errors.SpidersimError`) with the HTTP status and the service's message.

The server is not trusted: every answer is checked before it is used, and a broken or
hostile one ends in a :class:`RemoteError` naming the URL and what was wrong (exit status 2
in the CLI), never in a raw exception or a file written where it should not be:

- **deadlines**: every request must be complete, answer included, within ``timeout``
  seconds (:data:`REQUEST_TIMEOUT`); each socket operation waits at most until that
  deadline, so a server that drips one byte every few seconds is cut off on time (httpx's
  own read timeout restarts at every byte). :meth:`Client.wait` holds its requests to its
  own ``timeout`` too, and :meth:`Client.deadline` bounds a whole sequence of calls;
- **sizes**: a JSON answer may hold :data:`MAX_JSON_BYTES`, a data file
  :data:`MAX_DATA_BYTES`, a plot :data:`MAX_PLOT_BYTES`, one :meth:`Client.download`
  :data:`MAX_TOTAL_BYTES` in all and :data:`MAX_FILES` files (each a ``Client`` option);
  downloads stream to a hidden ``.NAME.*.part`` file in the folder, renamed when complete
  and removed on any error;
- **names**: a file name the server lists must be a bare name (letters, digits, ``.``,
  ``-``, ``_``, not starting with ``.``, at most 121 characters: the service's own rule), a
  data file one of :data:`DATA_FILES`, a plot a ``.png`` or ``.gif``; a job id letters,
  digits, ``-`` and ``_``;
- **redirects** are not followed (the token is sent only to the URL given); a redirect is
  an error naming its target.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import re
import tempfile
import threading
import time
import zipfile
from urllib.parse import quote

import numpy as np

from .errors import SpidersimError, printable
from .outputs import BARE_NAME
from .solver.result import Result

FINAL = ("done", "failed", "cancelled")

#: s: the longest one request may take, from connecting to the last byte of the answer
REQUEST_TIMEOUT = 30.0
#: bytes: the largest JSON answer (status, library, a signal, metadata) read
MAX_JSON_BYTES = 64 * 2**20
#: bytes: the largest data file (``result.npz``, ``result.csv``, ...) downloaded; the
#: service writes at most 64 MB of CSV and about its recording budget (256 MB) of NPZ
MAX_DATA_BYTES = 2**30
#: bytes: the largest plot (PNG, GIF animation) downloaded
MAX_PLOT_BYTES = 64 * 2**20
#: bytes: the most one :meth:`Client.download` writes in all
MAX_TOTAL_BYTES = 2 * 2**30
#: the most files one :meth:`Client.download` writes
MAX_FILES = 256
#: bytes of an error answer (HTTP >= 400) read for its message
MAX_ERROR_BYTES = 64 * 2**10
#: the data files of a job and the route suffix each is served under
DATA_FILES = {"result.npz": "npz", "result.csv": "csv", "report.txt": "txt",
              "meta.json": "json"}
PLOT_SUFFIXES = (".png", ".gif")

_CHUNK = 2**16
_JOB_ID = re.compile(r"[A-Za-z0-9_-]{1,128}\Z")
_STATE = re.compile(r"[a-z_]{1,32}\Z")


class RemoteError(SpidersimError):
    """An answer of the service other than success; ``status`` is the HTTP status."""

    def __init__(self, message, status=None):
        super().__init__(message)
        self.status = status


def result_from_npz(npz, meta):
    """A :class:`~spidersim.Result` from ``result.npz`` (bytes, path or file) and the job's
    ``meta.json`` content (dict): the inverse of ``Result.save`` plus metadata."""
    src = io.BytesIO(npz) if isinstance(npz, (bytes, bytearray)) else npz
    with np.load(src, allow_pickle=False) as z:
        t = z["t"]
        cols, slices, k = [], {}, 0
        for name, size in meta["sizes"].items():
            y = np.asarray(z[name], dtype=float).reshape(len(t), size)
            cols.append(y)
            slices[name] = (k, k + size)
            k += size
    data = np.hstack(cols) if cols else np.zeros((len(t), 0))
    events = [(float(a), str(b), str(c)) for a, b, c in meta.get("events", [])]
    return Result(t, data, slices, dict(meta.get("units", {})), events,
                  dict(meta.get("stats", {})), meta.get("status", "ok"),
                  meta.get("message", ""))


def _size(n):
    """``n`` bytes as a short text (``64 MiB``)."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.4g} {unit}"
    return f"{n} bytes"


def _kind(value):
    """What a JSON value is, for messages."""
    return {dict: "an object", list: "a list", str: "a text", bool: "a boolean",
            type(None): "null"}.get(type(value), "a number")


def _number(value):
    """True for a finite JSON number (not a boolean)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) \
        and math.isfinite(value)


def _clean(text):
    """A server's message with control characters escaped, line breaks kept."""
    return "\n".join(printable(line) for line in text.split("\n"))


def _positive(value, what):
    """``value`` as a float > 0, else a :class:`SpidersimError` naming ``what``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v > 0) or isinstance(value, bool):
        raise SpidersimError(f"Client: {what} must be a finite number > 0, got {value!r}")
    return v


def _check_encoding(r, url, status=""):
    """Refuse an answer with a ``Content-Encoding`` the client did not ask for (it sends
    ``Accept-Encoding: identity``), before reading it: its body is read undecoded
    (``iter_raw``) so that the size limits count the bytes on the wire; decoded, a
    1,828-byte ``gzip, gzip`` answer became 1 GiB (3.28 GB of peak memory)."""
    value = r.headers.get("content-encoding", "")
    if any(c.strip().lower() not in ("", "identity") for c in value.split(",")):
        raise RemoteError(f"{url}: {status}the answer is encoded '{printable(value)}' "
                          f"(Content-Encoding), which this client did not ask for (it sends "
                          f"Accept-Encoding: identity); not read", r.status_code)


def _env_proxy(url):
    """The proxy the environment (``http_proxy``, ``no_proxy``, ...) names for ``url``."""
    import urllib.parse
    import urllib.request
    proxies = urllib.request.getproxies()
    if not proxies:
        return None
    u = urllib.parse.urlsplit(url)
    if urllib.request.proxy_bypass(u.hostname or ""):
        return None
    return proxies.get(u.scheme) or proxies.get("all")


class _Deadline:
    """The end (``time.monotonic()``) of the current request of each thread, or None."""

    def __init__(self):
        self._local = threading.local()

    def get(self):
        return getattr(self._local, "end", None)

    def set(self, end):
        self._local.end = end

    def clamp(self, timeout, error):
        """``timeout`` shortened to the time left; ``error`` (an httpcore timeout class)
        raised when none is left."""
        end = self.get()
        if end is None:
            return timeout
        left = end - time.monotonic()
        if left <= 0:
            raise error("the request's deadline has passed")
        return left if timeout is None else min(timeout, left)


class _DeadlineStream:
    """An httpcore network stream whose every read and write ends by the deadline."""

    def __init__(self, stream, deadline):
        self._stream, self._deadline = stream, deadline

    def read(self, max_bytes, timeout=None):
        import httpcore
        return self._stream.read(max_bytes, self._deadline.clamp(timeout,
                                                                 httpcore.ReadTimeout))

    def write(self, buffer, timeout=None):
        import httpcore
        return self._stream.write(buffer, self._deadline.clamp(timeout,
                                                               httpcore.WriteTimeout))

    def close(self):
        self._stream.close()

    def start_tls(self, ssl_context, server_hostname=None, timeout=None):
        import httpcore
        inner = self._stream.start_tls(ssl_context, server_hostname,
                                       self._deadline.clamp(timeout, httpcore.ConnectTimeout))
        return _DeadlineStream(inner, self._deadline)

    def get_extra_info(self, info):
        return self._stream.get_extra_info(info)


class _DeadlineBackend:
    """httpcore's network backend with connections whose socket waits end by the
    deadline of the request (:class:`_Deadline`)."""

    def __init__(self, backend, deadline):
        self._backend, self._deadline = backend, deadline

    def connect_tcp(self, host, port, timeout=None, local_address=None, socket_options=None):
        import httpcore
        s = self._backend.connect_tcp(host, port,
                                      self._deadline.clamp(timeout, httpcore.ConnectTimeout),
                                      local_address, socket_options)
        return _DeadlineStream(s, self._deadline)

    def connect_unix_socket(self, path, timeout=None, socket_options=None):
        import httpcore
        s = self._backend.connect_unix_socket(
            path, self._deadline.clamp(timeout, httpcore.ConnectTimeout), socket_options)
        return _DeadlineStream(s, self._deadline)

    def sleep(self, seconds):
        self._backend.sleep(seconds)


class Client:
    """A session with one service; ``token`` defaults to ``$SPIDERSIM_TOKEN``.

    Parameters
    ----------
    url : str
        The service, ``http://host:port`` or ``https://...`` (a path prefix is kept).
    token : str, optional
        The user's token (``spidersim serve --add-user NAME``).
    timeout : float, optional
        s: the longest one request may take, answer included (default
        :data:`REQUEST_TIMEOUT`).
    max_json_bytes, max_data_bytes, max_plot_bytes, max_total_bytes : int, optional
        Size limits (bytes) of a JSON answer, a data file, a plot and one
        :meth:`download` in all (defaults: the module's ``MAX_*`` constants).
    """

    def __init__(self, url, token=None, timeout=None, max_json_bytes=None,
                 max_data_bytes=None, max_plot_bytes=None, max_total_bytes=None):
        import httpx
        token = token or os.environ.get("SPIDERSIM_TOKEN")
        if not token:
            raise RemoteError("no token: give token=... or set SPIDERSIM_TOKEN (the service's "
                              "administrator makes one with 'spidersim serve --add-user NAME')")
        self.url = str(url).rstrip("/")
        try:
            u = httpx.URL(self.url)
        except (httpx.InvalidURL, TypeError, ValueError) as exc:
            raise RemoteError(f"not a service URL: '{self.url}': {exc}") from None
        if u.scheme not in ("http", "https") or not u.host or u.query or u.fragment:
            raise RemoteError(f"not a service URL: '{self.url}' (expected http://HOST:PORT "
                              f"or https://..., without '?' or '#')")
        self.timeout = _positive(REQUEST_TIMEOUT if timeout is None else timeout, "timeout")
        lim = {}
        for name, value, default in (("max_json_bytes", max_json_bytes, MAX_JSON_BYTES),
                                     ("max_data_bytes", max_data_bytes, MAX_DATA_BYTES),
                                     ("max_plot_bytes", max_plot_bytes, MAX_PLOT_BYTES),
                                     ("max_total_bytes", max_total_bytes, MAX_TOTAL_BYTES)):
            lim[name] = int(_positive(default if value is None else value, name))
        self.max_json_bytes = lim["max_json_bytes"]
        self.max_data_bytes = lim["max_data_bytes"]
        self.max_plot_bytes = lim["max_plot_bytes"]
        self.max_total_bytes = lim["max_total_bytes"]
        self._deadline = _Deadline()
        try:
            transport = httpx.HTTPTransport(proxy=_env_proxy(self.url))
        except (ValueError, ImportError) as exc:         # a proxy httpx cannot use
            raise RemoteError(f"cannot reach the service at {self.url}: the proxy of the "
                              f"environment: {exc}") from None
        # every connection's socket waits end by the request's deadline: httpcore's pools
        # (also its proxies) take their network backend as an argument; httpx builds the
        # pool, so the backend is swapped in here (tests/test_remote_client.py's dripping
        # server fails if this stops working)
        pool = getattr(transport, "_pool", None)
        if pool is not None and hasattr(pool, "_network_backend"):
            pool._network_backend = _DeadlineBackend(pool._network_backend, self._deadline)
        self._http = httpx.Client(base_url=self.url, timeout=self.timeout,
                                  transport=transport, trust_env=False,
                                  follow_redirects=False,
                                  headers={"Authorization": f"Bearer {token}",
                                           "Accept-Encoding": "identity"})

    def close(self):
        self._http.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    @contextlib.contextmanager
    def deadline(self, seconds):
        """Context: every request made inside (in this thread) is complete within
        ``seconds`` from now, else :class:`RemoteError`; nested deadlines keep the earliest.
        ``with c.deadline(600): job = c.submit(...); c.wait(job); c.download(job, out)``
        bounds a whole run."""
        seconds = _positive(seconds, "deadline")
        old = self._deadline.get()
        end = time.monotonic() + seconds
        self._deadline.set(end if old is None else min(old, end))
        try:
            yield
        finally:
            self._deadline.set(old)

    # ------------------------------------------------------------------ HTTP
    def _job(self, job):
        """``job`` checked as a job id (it goes into URL paths)."""
        if not isinstance(job, str) or not _JOB_ID.match(job):
            raise RemoteError(f"{self.url}: not a job id: {job!r} (letters, digits, '-', '_')")
        return job

    def _request(self, method, path, limit, sink=None, too_big="", **kw):
        """One request; the answer's body (bytes), or its length when each chunk goes to
        ``sink``. Raise :class:`RemoteError` for an HTTP status >= 300 (redirects are not
        followed), a body longer than ``limit`` bytes (``too_big`` says which limit), no
        complete answer within ``self.timeout`` s (or an enclosing deadline), and a
        connection that fails."""
        import httpx
        url = self.url + path
        t0 = time.monotonic()
        with self.deadline(self.timeout):
            end = self._deadline.get()
            try:
                with self._http.stream(method, path, **kw) as r:
                    if r.status_code >= 300:
                        self._refuse(r, url)
                    _check_encoding(r, url)
                    declared = r.headers.get("content-length", "")
                    if declared.isdigit() and int(declared) > limit:
                        raise RemoteError(f"{url}: the answer announces {_size(int(declared))}"
                                          f", more than {too_big}; not read", r.status_code)
                    n, parts = 0, []
                    for chunk in r.iter_raw(_CHUNK):      # wire bytes, never decoded
                        n += len(chunk)
                        if n > limit:
                            raise RemoteError(f"{url}: the answer is longer than {too_big}; "
                                              f"stopped reading it", r.status_code)
                        if time.monotonic() > end:
                            raise httpx.ReadTimeout("the request's deadline has passed")
                        if sink is None:
                            parts.append(chunk)
                        else:
                            sink(chunk)
                    return r.status_code, (n if sink is not None else b"".join(parts))
            except httpx.TimeoutException:
                own = end - t0 >= self.timeout - 1e-3
                raise RemoteError(f"{url}: no complete answer within {max(0.0, end - t0):.3g} s (the "
                                  f"service is too slow or stalls"
                                  + ("; one request may take Client(timeout=...)" if own
                                     else "") + ")") from None
            except (httpx.HTTPError, httpx.InvalidURL) as exc:
                raise RemoteError(f"cannot reach the service at {self.url}: {exc}") from None

    def _refuse(self, r, url):
        """Raise the :class:`RemoteError` of an answer with status >= 300."""
        if r.status_code < 400:
            where = printable(r.headers.get("location", "(no Location)"))
            raise RemoteError(f"{url}: HTTP {r.status_code}: a redirect to '{where}', not "
                              f"followed (the token is sent only to {self.url})",
                              status=r.status_code)
        _check_encoding(r, url, f"HTTP {r.status_code}: ")
        body = b""
        for chunk in r.iter_raw(_CHUNK):
            body += chunk
            if len(body) >= MAX_ERROR_BYTES:
                break
        text = body[:MAX_ERROR_BYTES].decode("utf-8", "replace")
        detail = text
        try:
            content = json.loads(text)
        except (ValueError, RecursionError):
            content = None
        if isinstance(content, dict) and "detail" in content:
            detail = content["detail"]
            if isinstance(detail, list):          # pydantic validation errors
                detail = "; ".join(
                    f"{'.'.join(str(x) for x in e.get('loc', []))}: {e.get('msg')}"
                    if isinstance(e, dict) and isinstance(e.get("loc", []), list)
                    else str(e) for e in detail)
        detail = str(detail)
        if len(detail) > 2000:
            detail = detail[:2000] + " [...]"
        raise RemoteError(f"{url}: HTTP {r.status_code}: {detail}", status=r.status_code)

    def _json(self, method, path, kind, what, **kw):
        """A request whose answer must be JSON of type ``kind`` (``what`` names it)."""
        url = self.url + path
        status, body = self._request(method, path, self.max_json_bytes,
                                     too_big=f"the {_size(self.max_json_bytes)} this client "
                                             f"reads of a JSON answer (Client("
                                             f"max_json_bytes=...))", **kw)
        if not body.strip():
            raise RemoteError(f"{url}: an empty answer (HTTP {status}) where {what} was "
                              f"expected", status)
        try:
            value = json.loads(body)
        except (ValueError, RecursionError) as exc:
            raise RemoteError(f"{url}: not JSON ({type(exc).__name__}: {exc}) where {what} "
                              f"was expected; it begins "
                              f"{body[:80].decode('utf-8', 'replace')!r}", status) from None
        if not isinstance(value, kind):
            raise RemoteError(f"{url}: {_kind(value)} where {what} was expected", status)
        return value

    def _status(self, st, url):
        """A job status checked: ``state`` a name, ``progress`` and ``t_end`` finite
        numbers, ``message`` a text (control characters escaped), ``files`` (if present)
        ``{data: [...], plots: [...]}``."""
        state = st.get("state")
        if not isinstance(state, str) or not _STATE.match(state):
            raise RemoteError(f"{url}: the job status has no valid 'state' (got "
                              f"{_kind(state) if not isinstance(state, str) else repr(state)}"
                              f"; expected one of queued, running, {', '.join(FINAL)})")
        for key in ("progress", "t_end"):
            if not _number(st.get(key)):
                raise RemoteError(f"{url}: the job status' '{key}' is "
                                  f"{_kind(st.get(key)) if key in st else 'missing'}"
                                  f"{' ' + repr(st[key]) if isinstance(st.get(key), str) else ''}"
                                  f", not a finite number of seconds")
        msg = st.get("message", "")
        if msg is None:
            msg = ""
        if not isinstance(msg, str):
            raise RemoteError(f"{url}: the job status' 'message' is {_kind(msg)}, not a text")
        st["message"] = _clean(msg)
        if "files" in st:
            files = st["files"]
            if not isinstance(files, dict) or not all(
                    isinstance(files.get(k, []), list) for k in ("data", "plots")):
                raise RemoteError(f"{url}: the job status' 'files' is {_kind(files)}, not "
                                  f"{{\"data\": [names], \"plots\": [names]}}")
        return st

    # ------------------------------------------------------------------ library
    def models(self):
        """``[{name, title, description}]`` of the service's library."""
        return self._json("GET", "/models", list, "the list of models")

    def model(self, name):
        """The full description of one model (parameters, commands, signals, arm data)."""
        return self._json("GET", f"/models/{quote(str(name), safe='')}", dict,
                          "a model's description (an object)")

    # ------------------------------------------------------------------ jobs
    def submit(self, model, parameters=None, initial=None, t_end=None, command=None,
               log=None, plots=True, key=None):
        """Queue a run; return the job id at once. ``key``: an idempotency key (a retried
        submit with the same key returns the first job)."""
        body = {"model": model, "parameters": parameters or {}, "initial": initial or {},
                "plots": plots}
        if t_end is not None:
            body["t_end"] = t_end
        if command is not None:
            body["command"] = command
        if log is not None:
            body["log"] = list(log)
        headers = {"Idempotency-Key": key} if key else {}
        ans = self._json("POST", "/jobs", dict, "the new job ({\"id\": ...})", json=body,
                         headers=headers)
        job = ans.get("id")
        if not isinstance(job, str) or not _JOB_ID.match(job):
            raise RemoteError(f"{self.url}/jobs: the service gave the job id "
                              f"{job!r}, not letters, digits, '-' and '_'")
        return job

    def status(self, job):
        """The job's status: ``{id, state, progress, t_end, message, files, ...}``."""
        path = f"/jobs/{self._job(job)}"
        return self._status(self._json("GET", path, dict, "the job's status (an object)"),
                            self.url + path)

    def jobs(self):
        return self._json("GET", "/jobs", list, "the list of jobs")

    def wait(self, job, timeout=None, poll=0.2):
        """Poll until the job is done, failed or cancelled; return its status. With
        ``timeout`` (s), the requests too end by then, else :class:`RemoteError`."""
        self._job(job)
        t0 = time.monotonic()
        ctx = self.deadline(timeout) if timeout is not None else contextlib.nullcontext()
        st = None
        with ctx:
            while True:
                if st is not None and timeout is not None and \
                        time.monotonic() - t0 >= timeout:
                    raise RemoteError(f"job {job} still {st['state']} after {timeout:g} s "
                                      f"(t = {st['progress']:g} / {st['t_end']:g} s)")
                try:
                    st = self.status(job)
                except RemoteError as exc:
                    if timeout is not None and time.monotonic() - t0 >= timeout:
                        raise RemoteError(f"job {job}: no final status within {timeout:g} s: "
                                          f"{exc.message}", exc.status) from None
                    raise
                if st["state"] in FINAL:
                    return st
                left = poll if timeout is None else timeout - (time.monotonic() - t0)
                time.sleep(max(0.0, min(poll, left)))

    def cancel(self, job):
        return self._json("POST", f"/jobs/{self._job(job)}/cancel", dict,
                          "the job's status (an object)")

    def delete(self, job):
        """Remove a finished job's files on the service (it stays listed, ``expired``;
        its results answer 410); frees its bytes of the user's disk quota. Return the
        job's status. A queued or running job is refused (cancel it first)."""
        path = f"/jobs/{self._job(job)}"
        return self._status(self._json("DELETE", path, dict, "the job's status (an object)"),
                            self.url + path)

    def usage(self):
        """The user's disk use and quota: ``{used_bytes, quota_bytes, free_bytes,
        stored_bytes, reserved_bytes, active_jobs, largest, ...}``."""
        return self._json("GET", "/usage", dict, "the disk use (an object)")

    def result(self, job):
        """The job's :class:`~spidersim.Result` (also for a failed run: the data up to the
        failure, ``status == "failed"`` and the message; and for a run cancelled while
        running: the data up to where it stopped, ``status == "cancelled"``)."""
        st = self.status(job)
        data = st.get("files", {}).get("data", [])
        if st["state"] not in ("done", "failed", "cancelled") or "result.npz" not in data:
            raise RemoteError(f"job {job} is {st['state']}"
                              + (f": {st['message']}" if st["message"] else "")
                              + "; it has no result")
        meta = self._json("GET", f"/jobs/{job}/result.json", dict,
                          "the job's metadata (an object)")
        _, npz = self._request("GET", f"/jobs/{job}/result.npz", self.max_data_bytes,
                               too_big=f"the {_size(self.max_data_bytes)} this client reads "
                                       f"of a data file (Client(max_data_bytes=...))")
        url = f"{self.url}/jobs/{job}/result.npz"
        try:
            with zipfile.ZipFile(io.BytesIO(npz)) as zf:
                unpacked = sum(i.file_size for i in zf.infolist())
            if unpacked > self.max_data_bytes:
                raise RemoteError(f"{url}: unpacks to {_size(unpacked)}, more than the "
                                  f"{_size(self.max_data_bytes)} of Client(max_data_bytes"
                                  f"=...)")
            return result_from_npz(npz, meta)
        except (zipfile.BadZipFile, KeyError, ValueError, TypeError, AttributeError,
                IndexError, OSError, EOFError, MemoryError) as exc:
            raise RemoteError(f"{url} and result.json do not make a result: "
                              f"{type(exc).__name__}: {exc}") from None

    def signal(self, job, name, stride=1):
        """One signal as ``{t, values, unit}`` (decimated by ``stride``)."""
        path = f"/jobs/{self._job(job)}/signals/{quote(str(name), safe='')}.json"
        sig = self._json("GET", path, dict, "a signal ({t, values, unit})",
                         params={"stride": stride})
        if not (isinstance(sig.get("t"), list) and isinstance(sig.get("values"), list)):
            raise RemoteError(f"{self.url}{path}: the signal has no lists 't' and 'values'")
        return sig

    def _plan(self, job, st, url):
        """``[(name, route, limit, limit text)]`` of the files a status lists, every name
        checked before anything is written."""
        files = st.get("files", {})
        data, plots = files.get("data", []), files.get("plots", [])
        if len(data) + len(plots) > MAX_FILES:
            raise RemoteError(f"{url}: the job lists {len(data) + len(plots)} files, more "
                              f"than this client's limit of {MAX_FILES}; nothing written")
        out, seen = [], set()
        for kind, names in (("data", data), ("plot", plots)):
            for name in names:
                bare = isinstance(name, str) and BARE_NAME.match(name) is not None
                if not bare or name in seen:
                    raise RemoteError(
                        f"{url}: the service at {self.url} names a {kind} file "
                        f"{name!r}: " + ("listed twice" if bare else
                                         "not a bare file name (letters, digits, '.', '-', "
                                         "'_', not starting with '.', at most 121 "
                                         "characters)") + "; nothing written")
                seen.add(name)
                if kind == "data":
                    if name not in DATA_FILES:
                        raise RemoteError(f"{url}: the service names a data file '{name}', "
                                          f"not one of {', '.join(DATA_FILES)}; nothing "
                                          f"written")
                    out.append((name, f"/jobs/{job}/result.{DATA_FILES[name]}",
                                self.max_data_bytes, "max_data_bytes"))
                else:
                    if not name.endswith(PLOT_SUFFIXES):
                        raise RemoteError(f"{url}: the service names a plot '{name}', not a "
                                          f"{' or '.join(PLOT_SUFFIXES)} file; nothing "
                                          f"written")
                    out.append((name, f"/jobs/{job}/plots/{name}",
                                self.max_plot_bytes, "max_plot_bytes"))
        return out

    def download(self, job, folder):
        """Write the job's data files and plots into ``folder``; return the paths.

        Every name is checked first (nothing is written if one is not a bare file name);
        each file streams to a ``.NAME.*.part`` file in ``folder``, renamed to ``NAME`` when
        complete and removed if the transfer fails or passes a size limit."""
        path = f"/jobs/{self._job(job)}"
        st = self.status(job)
        plan = self._plan(job, st, self.url + path)
        try:
            os.makedirs(folder, exist_ok=True)
        except OSError as exc:
            raise SpidersimError(f"cannot make the folder '{folder}': "
                                 f"{exc.strerror or exc}") from None
        out, total = [], 0
        for name, route, limit, option in plan:
            left = self.max_total_bytes - total
            too_big = (f"the {_size(limit)} this client takes of one file (Client({option}"
                       f"=...))" if limit <= left else
                       f"the {_size(left)} left of the {_size(self.max_total_bytes)} this "
                       f"client takes of one download (Client(max_total_bytes=...))")
            dest = os.path.join(folder, name)
            try:
                fd, part = tempfile.mkstemp(prefix=f".{name}.", suffix=".part", dir=folder)
            except OSError as exc:
                raise SpidersimError(f"cannot write in '{folder}': "
                                     f"{exc.strerror or exc}") from None
            try:
                with os.fdopen(fd, "wb") as fh:
                    _, n = self._request("GET", route, min(limit, left), sink=fh.write,
                                         too_big=too_big)
                os.replace(part, dest)
            except OSError as exc:
                with contextlib.suppress(OSError):
                    os.unlink(part)
                raise SpidersimError(f"cannot write '{dest}': {exc.strerror or exc}") from None
            except BaseException:
                with contextlib.suppress(OSError):
                    os.unlink(part)
                raise
            total += n
            out.append(dest)
        return out


__all__ = ["Client", "RemoteError", "result_from_npz", "FINAL", "REQUEST_TIMEOUT",
           "MAX_JSON_BYTES", "MAX_DATA_BYTES", "MAX_PLOT_BYTES", "MAX_TOTAL_BYTES",
           "MAX_FILES", "DATA_FILES"]
