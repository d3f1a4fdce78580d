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
"""
from __future__ import annotations

import io
import os
import time

import numpy as np

from .errors import SpidersimError
from .solver.result import Result

FINAL = ("done", "failed", "cancelled")


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


class Client:
    """A session with one service; ``token`` defaults to ``$SPIDERSIM_TOKEN``."""

    def __init__(self, url, token=None, timeout=30.0):
        import httpx
        token = token or os.environ.get("SPIDERSIM_TOKEN")
        if not token:
            raise RemoteError("no token: give token=... or set SPIDERSIM_TOKEN (the service's "
                              "administrator makes one with 'spidersim serve --add-user NAME')")
        self.url = url.rstrip("/")
        self._http = httpx.Client(base_url=self.url, timeout=timeout,
                                  headers={"Authorization": f"Bearer {token}"})

    def close(self):
        self._http.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _call(self, method, path, **kw):
        import httpx
        try:
            r = self._http.request(method, path, **kw)
        except httpx.HTTPError as exc:
            raise RemoteError(f"cannot reach the service at {self.url}: {exc}") from None
        if r.status_code >= 400:
            try:
                detail = r.json().get("detail", r.text)
            except ValueError:
                detail = r.text
            if isinstance(detail, list):          # pydantic validation errors
                detail = "; ".join(f"{'.'.join(str(x) for x in e.get('loc', []))}: "
                                   f"{e.get('msg')}" for e in detail)
            raise RemoteError(f"{self.url}{path}: HTTP {r.status_code}: {detail}",
                              status=r.status_code)
        return r

    # ------------------------------------------------------------------ library
    def models(self):
        """``[{name, title, description}]`` of the service's library."""
        return self._call("GET", "/models").json()

    def model(self, name):
        """The full description of one model (parameters, commands, signals, arm data)."""
        return self._call("GET", f"/models/{name}").json()

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
        return self._call("POST", "/jobs", json=body, headers=headers).json()["id"]

    def status(self, job):
        return self._call("GET", f"/jobs/{job}").json()

    def jobs(self):
        return self._call("GET", "/jobs").json()

    def wait(self, job, timeout=None, poll=0.2):
        """Poll until the job is done, failed or cancelled; return its status."""
        t0 = time.monotonic()
        while True:
            st = self.status(job)
            if st["state"] in FINAL:
                return st
            if timeout is not None and time.monotonic() - t0 > timeout:
                raise RemoteError(f"job {job} still {st['state']} after {timeout:g} s "
                                  f"(t = {st['progress']:g} / {st['t_end']:g} s)")
            time.sleep(poll)

    def cancel(self, job):
        return self._call("POST", f"/jobs/{job}/cancel").json()

    def result(self, job):
        """The job's :class:`~spidersim.Result` (also for a failed run: the data up to the
        failure, ``status == "failed"`` and the message)."""
        st = self.status(job)
        if st["state"] not in ("done", "failed") or "result.npz" not in st.get(
                "files", {}).get("data", []):
            raise RemoteError(f"job {job} is {st['state']}"
                              + (f": {st['message']}" if st["message"] else "")
                              + "; it has no result")
        meta = self._call("GET", f"/jobs/{job}/result.json").json()
        npz = self._call("GET", f"/jobs/{job}/result.npz").content
        return result_from_npz(npz, meta)

    def signal(self, job, name, stride=1):
        """One signal as ``{t, values, unit}`` (decimated by ``stride``)."""
        return self._call("GET", f"/jobs/{job}/signals/{name}.json",
                          params={"stride": stride}).json()

    def download(self, job, folder):
        """Write the job's data files and plots into ``folder``; return the paths."""
        st = self.status(job)
        files = st.get("files", {"data": [], "plots": []})
        os.makedirs(folder, exist_ok=True)
        ext = {"result.npz": "npz", "result.csv": "csv", "report.txt": "txt",
               "meta.json": "json"}
        out = []
        for n in files["data"]:
            p = os.path.join(folder, n)
            with open(p, "wb") as fh:
                fh.write(self._call("GET", f"/jobs/{job}/result.{ext[n]}").content)
            out.append(p)
        for n in files["plots"]:
            p = os.path.join(folder, n)
            with open(p, "wb") as fh:
                fh.write(self._call("GET", f"/jobs/{job}/plots/{n}").content)
            out.append(p)
        return out


__all__ = ["Client", "RemoteError", "result_from_npz", "FINAL"]
