"""The HTTP application (FastAPI): models, jobs, results, the web page.

Every route but ``GET /health``, ``/`` and the page's static files needs
``Authorization: Bearer <token>`` (401 otherwise; for a request with a body, before any
of it is read); a job of another user answers 404 as an
unknown one. Limits answer 413 (body size, a signal answer of more than ``max_points``
values), 422 (run length, logged signals, bad request, a non-finite number, nesting deeper
than ``MAX_DEPTH``) and 429 (active jobs or open event streams per user, with
``Retry-After``) and 507 (the user's disk quota ``max_user_mb``), each with a ``detail``
message; the files of a job finished more than ``keep_days`` ago, or
deleted by its user (``DELETE /jobs/{id}``), are removed and its result routes answer 410
Gone. ``GET /usage`` gives the user's disk use and quota.

Every JSON answer is strict JSON (RFC 8259): a non-finite number in a stored value or a
result (a run whose rows hold inf or nan) is written as ``null``
(:class:`StrictJSONResponse`); a request holding one (``1e999``, ``Infinity``, ``NaN``) is
refused with 422 naming its field.
"""
from __future__ import annotations

import asyncio
import json
import math
import os
import re
import shutil
import threading
import time
import weakref
import zipfile
from typing import Annotated, Any, Literal, Optional, Union

import numpy as np
from fastapi import Depends, FastAPI, Header, HTTPException, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, model_validator

import spidersim
from spidersim.errors import SpidersimError
from spidersim.outputs import BARE_NAME
from spidersim.text.limits import MAX_DEPTH
from spidersim.text.yamlio import lone_surrogate

from .body import BodyLimit
from .commands import prepare
from .execute import finite_json
from .library import BadName, Library, UnknownModel
from .store import KeyReused, OverQuota, Store, TooManyJobs

STATIC = os.path.join(os.path.dirname(os.path.abspath(__file__)), "static")


class Limits(BaseModel):
    max_body: int = 256 * 1024          # bytes of a request body
    max_t_end: float = 60.0              # s of simulated time per run
    max_signals: int = 64                # signals a request's 'log' may name
    max_active: int = 8                  # queued + running jobs per user
    max_streams: int = 8                 # open event streams per user
    max_record_mb: float = 256.0         # recording budget of one job [MB = 1e6 bytes]
    max_points: int = 200_000            # values (samples x elements) of one /signals answer
    keep_days: float = 7.0               # days a finished job's files are kept
    max_user_mb: float = 4096.0          # disk quota of one user's jobs [MB = 1e6 bytes]

    @model_validator(mode="after")
    def _quota_holds_a_job(self):
        """Every job reserves ``max_record_mb`` of the quota: a smaller quota takes none."""
        for name in ("max_user_mb", "max_record_mb", "keep_days", "max_t_end"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v}")
        if self.max_user_mb < self.max_record_mb:
            raise ValueError(f"max_user_mb = {self.max_user_mb:g} is less than max_record_mb "
                             f"= {self.max_record_mb:g}: no job could be submitted")
        return self


def dumps_strict(content) -> str:
    """Strict JSON text of ``content``: non-finite numbers as ``null`` (never the
    ``Infinity``/``NaN`` tokens, which are not JSON and which browsers refuse)."""
    try:
        return json.dumps(content, allow_nan=False, ensure_ascii=False,
                          separators=(",", ":"))
    except ValueError:
        return json.dumps(finite_json(content), allow_nan=False, ensure_ascii=False,
                          separators=(",", ":"))


class StrictJSONResponse(JSONResponse):
    """The app's JSON answers: non-finite numbers written as ``null`` (Starlette's
    response raised ``ValueError: Out of range float values`` -> 500, and a job stored
    with an infinite value made every later job list of its user a 500)."""

    def render(self, content) -> bytes:
        return dumps_strict(content).encode("utf-8")


def non_finite_field(v, where="body"):
    """The path (``body.parameters.V_max``) of the first non-finite number in a parsed
    request, or None."""
    stack = [(v, where)]
    while stack:
        x, w = stack.pop()
        if isinstance(x, float) and not math.isfinite(x):
            return w
        if isinstance(x, dict):
            stack += [(y, f"{w}.{k}") for k, y in x.items()]
        elif isinstance(x, list):
            stack += [(y, f"{w}[{i}]") for i, y in enumerate(x)]
    return None


def too_deep(v, where="body", limit=MAX_DEPTH):
    """Where (``body.parameters.motor.R``) lists and objects of a parsed request nest more
    than ``limit`` deep, or None; counted without recursion (a value 328 lists deep made
    the diagram loader's recursion fail: a 500 and a 195 KB traceback in the log)."""
    stack = [(v, where, 1)]
    while stack:
        x, w, d = stack.pop()
        if isinstance(x, (dict, list)):
            if d > limit:
                return w
            items = x.items() if isinstance(x, dict) else enumerate(x)
            stack += [(y, (f"{w}.{k}" if isinstance(x, dict) else f"{w}[{k}]")
                       if d < 4 else w, d + 1) for k, y in items]
    return None


def shallow(v, limit=MAX_DEPTH):
    """``v`` with lists and objects nested deeper than ``limit`` replaced by ``"[...]"``:
    a 422 quotes the input, and encoding one nested 483 deep failed (a 500)."""
    if isinstance(v, (dict, list)) and limit <= 0:
        return "[...]"
    if isinstance(v, dict):
        return {k: shallow(x, limit - 1) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [shallow(x, limit - 1) for x in v]
    return v


# ---------------------------------------------------------------------------- request types
#: a number of a request: JSON int or float; true/false and texts ("2") are refused (lax
#: pydantic would read true as 1.0, so ``"t_end": true`` ran for 1 s)
Number = Annotated[float, Field(strict=True)]

class Quantity(BaseModel):
    """A value with its unit (Modelica notation), converted to the declared unit."""
    model_config = ConfigDict(extra="forbid")
    value: Union[Number, list[Number]]
    unit: str = Field(max_length=100, description="e.g. mOhm, deg, rpm, mm, N.m")


class TableCommand(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["table"]
    block: Optional[str] = Field(None, description="source block to replace")
    time: list[Number] = Field(description="strictly increasing times [s]")
    value: list[Number] = Field(description="values at those times (unit of the input fed)")
    unit: Optional[str] = Field(None, max_length=100,
                                description="unit of the values (default: the model's)")


class JointPathCommand(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["joint_path"]
    block: Optional[str] = Field(None, description="trajectory block")
    points: list[Number] = Field(description="via points (joint units); more than 2 "
                                "replace the block by a ViaPointProfile")
    times: list[Number] = Field(description="times of the via points [s], strictly increasing")
    unit: Optional[str] = Field(None, max_length=100,
                                description="unit of the points (default: the joint's, rad)")


class CartesianLineCommand(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["cartesian_line"]
    ik: Optional[str] = None
    direction: list[Number] = Field(description="line direction, base frame")
    distance: Optional[Union[Number, Quantity]] = Field(None, description="path length [m]")
    speed: Optional[Union[Number, Quantity]] = Field(None, description="cruise speed [m/s]")
    accel: Optional[Union[Number, Quantity]] = Field(None,
                                                    description="path acceleration [m/s2]")
    t_start: Optional[Union[Number, Quantity]] = Field(None, description="start time [s]")


class NamedCommand(BaseModel):
    model_config = ConfigDict(extra="forbid")
    kind: Literal["named"]
    name: str
    arguments: dict[str, Any] = {}


Command = Annotated[Union[TableCommand, JointPathCommand, CartesianLineCommand, NamedCommand],
                    Field(discriminator="kind")]
Value = Union[float, int, bool, str, list, Quantity]


class RunRequest(BaseModel):
    """A run: model, parameter and initial-state overrides, run length, command."""
    model_config = ConfigDict(extra="forbid")
    model: str = Field(description="model name from GET /models")
    parameters: dict[str, Value] = Field({}, description="'name' or 'block.param' -> value")
    initial: dict[str, Value] = Field({}, description="'block.state' -> initial value")
    t_end: Optional[Number] = Field(None, description="simulated time [s]")
    log: Optional[list[str]] = Field(None, description="signals to record")
    command: Optional[Command] = None
    plots: bool = Field(True, description="draw the model's plots")

    @model_validator(mode="before")
    @classmethod
    def _characters(cls, data):
        """Refuse texts holding a lone surrogate (JSON ``\\ud800`` escapes): not a
        character, it cannot be printed, stored or written to a file; and non-finite
        numbers (``1e999`` overflows to inf; ``Infinity``, ``NaN``): not JSON, they cannot
        be answered back (an infinite value is given as the text ``"inf"``); and lists or
        objects nested more than ``MAX_DEPTH`` deep (checked first, without recursion)."""
        deep = too_deep(data)
        if deep is not None:
            raise ValueError(f"{deep}: lists and objects nested more than {MAX_DEPTH} deep "
                             f"(the limit MAX_DEPTH of diagram files)")
        bad = non_finite_field(data)
        if bad is not None:
            raise ValueError(f"{bad}: a non-finite number (1e999 overflows to inf, Infinity, "
                             f"NaN) is not a JSON number; give a finite value (a parameter "
                             f"that may be infinite takes the text \"inf\")")
        stack = [(data, "body")]
        while stack:
            v, where = stack.pop()
            if isinstance(v, str):
                if lone_surrogate(v):
                    raise ValueError(f"{where}: a lone surrogate escape (\\ud800-\\udfff) "
                                     f"is not a character")
            elif isinstance(v, dict):
                stack += [(k, f"{where}: a key") for k in v]
                stack += [(x, f"{where}.{k}" if isinstance(k, str) and not lone_surrogate(
                    k) else where) for k, x in v.items()]
            elif isinstance(v, list):
                stack += [(x, f"{where}[{i}]") for i, x in enumerate(v)]
        return data


def bearer(authorization):
    """The token of an ``Authorization: Bearer <token>`` header, or None."""
    if authorization and authorization.lower().startswith("bearer "):
        return authorization[7:].strip()
    return None


#: the 401 detail
NO_TOKEN = ("a valid token is required: send 'Authorization: Bearer <token>' (an "
            "administrator makes one with 'spidersim serve --add-user NAME')")


def current_user(request: Request,
                 authorization: Annotated[Optional[str], Header()] = None):
    """The (user id, name) of the request's bearer token; 401 without a valid one."""
    tok = bearer(authorization)
    u = request.app.state.store.user_for_token(tok) if tok else None
    if u is None:
        raise HTTPException(401, NO_TOKEN, headers={"WWW-Authenticate": "Bearer"})
    return u


def token_gate(store, public, under=()):
    """The :class:`BodyLimit` gate: a request to a path neither in ``public`` (a set of
    paths) nor starting with one of ``under`` (a tuple) is refused with 401 unless its
    first ``Authorization`` header holds a valid bearer token, before its body is read."""
    def gate(scope):
        path = scope["path"]
        if path in public or path.startswith(under):
            return None
        auth = next((v.decode("latin-1") for k, v in scope["headers"]
                     if k.lower() == b"authorization"), None)
        tok = bearer(auth)
        if tok and store.user_for_token(tok) is not None:
            return None
        return 401, NO_TOKEN, [(b"www-authenticate", b"Bearer")]
    return gate


User = Annotated[tuple, Depends(current_user)]


def read_rows(path, name, stride, chunk_rows=1 << 16):
    """Every ``stride``-th row of array ``name`` of an NPZ written by ``Result.save``
    (entries stored, not compressed), read from the file in blocks of ``chunk_rows`` rows:
    the answer's memory is the rows returned plus one block, not the whole array (six
    parallel requests for 63 MB signals took the server from 230 MB to 2.1 GB).
    Returns ``(n_rows, array)``; ``stride=None`` reads only the row count."""
    fmt = np.lib.format
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(name + ".npy")
        with zf.open(info) as f:
            version = fmt.read_magic(f)
            read = fmt.read_array_header_1_0 if version == (1, 0) else \
                fmt.read_array_header_2_0
            shape, fortran, dtype = read(f)
            head = f.tell()
        n = shape[0] if shape else 1
        if stride is None:
            return n, None
        if info.compress_type != zipfile.ZIP_STORED or fortran or dtype.hasobject:
            with np.load(path, allow_pickle=False) as z:          # not ours: plain load
                return n, np.ascontiguousarray(z[name][::stride])
    width = int(np.prod(shape[1:])) if len(shape) > 1 else 1
    row = width * dtype.itemsize
    with open(path, "rb") as fh:                  # the entry's data in the ZIP file
        fh.seek(info.header_offset)
        local = fh.read(30)
        start = info.header_offset + 30 + int.from_bytes(local[26:28], "little") \
            + int.from_bytes(local[28:30], "little") + head
        parts = []
        step = max(stride, (chunk_rows // stride) * stride)
        for lo in range(0, n, step):
            hi = min(n, lo + step)
            fh.seek(start + lo * row)
            block = np.frombuffer(fh.read((hi - lo) * row), dtype=dtype)
            parts.append(block.reshape((hi - lo,) + tuple(shape[1:]))[::stride].copy())
    out = np.concatenate(parts) if parts else np.zeros((0,) + tuple(shape[1:]), dtype)
    return n, out


def _mb(n):
    """``n`` bytes as MB (1e6 bytes, the unit of the limits): ``12.3 MB``."""
    return f"{n / 1e6:.4g} MB"


def quota_message(use, reserve, limit, largest, keep_days, now):
    """The 507 answer of a submit over the user's quota: what is used (stored results,
    active jobs' reservations), the quota, and the way out (the largest jobs to delete,
    when retention frees the oldest, or waiting for the active jobs).

    ``use``: :meth:`Store.usage`; ``reserve`` and ``limit`` in bytes; ``largest``:
    :meth:`Store.largest_jobs`; ``now``: time.time()."""
    n = use["active"]
    text = (f"this job would take your disk use over your quota of {_mb(limit)}: your "
            f"stored results take {_mb(use['stored'])}, your {n} queued or running job(s) "
            f"reserve {_mb(use['used'] - use['stored'])} and this job {_mb(reserve)} "
            f"(a job's reservation is the recording budget per job; a finished job counts "
            f"the size of its files)")
    ways = []
    if largest:
        big = ", ".join(f"{jid} ({model}, {_mb(b)})" for jid, model, b, _ in largest)
        ways.append(f"delete results you no longer need with DELETE /jobs/{{id}} "
                    f"(Client.delete(job)); your largest: {big}")
        left = max(0.0, min(f for *_, f in largest) + keep_days * 86400.0 - now)
        when = f"{left / 3600:.3g} h" if left < 2 * 86400 else f"{left / 86400:.3g} days"
        ways.append(f"wait: results are removed {keep_days:g} day(s) after their job ends "
                    f"(the oldest of these in {when})")
    if n:
        ways.append("wait for your active jobs to finish (their files then count instead "
                    "of the reservation)")
    if not ways:
        ways.append("ask the service's administrator for a larger quota (serve "
                    "--max-user-mb)")
    return text + "; to free space: " + "; or ".join(ways) + " (GET /usage shows your use)"


def create_app(data_dir, models=None, runner_factory=None, limits: Limits | None = None):
    """The ASGI app; ``runner_factory(store, library) -> Runner`` starts the workers."""
    limits = limits or Limits()
    store = Store(data_dir)
    library = Library(models)
    state = {"runner": None}
    keep_s = limits.keep_days * 86400.0

    def expired(job):
        """A finished job whose files are past the retention time (removed, or about to
        be by the sweeper)."""
        return bool(job.get("expired")) or (
            job["state"] in ("done", "failed", "cancelled") and job["finished"] is not None
            and time.time() - job["finished"] > keep_s)

    reserve = limits.max_record_mb * 1e6      # bytes reserved for each active job
    quota = limits.max_user_mb * 1e6

    def since():
        """The end time of the oldest finished job whose files are kept."""
        return time.time() - keep_s

    def sweep():
        """Remove the files of jobs finished more than ``keep_days`` ago; return how many."""
        ids = store.expire(time.time() - keep_s)
        for jid in ids:
            shutil.rmtree(store.job_dir(jid), ignore_errors=True)
        return len(ids)

    def sweeper(stop):
        while not stop.wait(min(600.0, max(0.5, keep_s / 10))):
            try:
                sweep()
            except Exception as exc:              # database busy: next time
                print(f"spidersim serve: result clean-up failed: {exc}", flush=True)

    def kept_data(job):
        """A cancelled job that stopped cooperatively and wrote its files (signals.json is
        written last); one that was killed has none."""
        return job["state"] == "cancelled" and os.path.isfile(
            os.path.join(store.job_dir(job["id"]), "signals.json"))

    def _files(job):
        folder = store.job_dir(job["id"])
        out = {"data": [], "plots": []}
        for n in ("result.npz", "result.csv", "report.txt", "meta.json"):
            if os.path.isfile(os.path.join(folder, n)):
                out["data"].append(n)
        pl = os.path.join(folder, "plots")
        if os.path.isdir(pl):
            out["plots"] = sorted(os.listdir(pl))
        return out

    def _public(job, request=True):
        """A job as answered; ``request=False`` leaves out the stored request (the job list
        and the event stream: 1000 listed jobs of 256 KiB requests built 260 MB per call;
        GET /jobs/{id} has it)."""
        j = {k: job[k] for k in ("id", "model", "state", "t_end", "progress", "message",
                                 "created", "started", "finished", "version", "diagram_hash")}
        if request:
            j["request"] = job["request"]
        j["fraction"] = min(1.0, job["progress"] / job["t_end"]) if job["t_end"] > 0 else 1.0
        j["expired"] = expired(job)
        j["bytes"] = 0 if j["expired"] else job["bytes"]
        if job["state"] in ("done", "failed") or kept_data(job):
            j["files"] = {"data": [], "plots": []} if j["expired"] else _files(job)
        return j

    async def lifespan(app):
        failed, queued = store.recover()
        if failed or queued:
            print(f"spidersim serve: {failed} job(s) were running when the server stopped "
                  f"(marked failed), {queued} queued job(s) will run", flush=True)
        n = sweep()
        if n:
            print(f"spidersim serve: removed the files of {n} job(s) finished more than "
                  f"{limits.keep_days:g} day(s) ago", flush=True)
        stop = threading.Event()
        threading.Thread(target=sweeper, args=(stop,), daemon=True,
                         name="spidersim-retention").start()
        if runner_factory is not None:
            state["runner"] = runner_factory(store, library)
            state["runner"].start()
        yield
        stop.set()
        if state["runner"] is not None:
            state["runner"].stop()

    app = FastAPI(title="spidersim service (SIMECS-RI)", version=spidersim.__version__,
                  description="Remote simulation of spidersim models: pick a model, set "
                              "parameters, initial state and a command, run, fetch results. "
                              "Authorize with 'Authorization: Bearer <token>' (a token comes "
                              "from 'spidersim serve --add-user NAME').",
                  lifespan=lifespan, default_response_class=StrictJSONResponse)
    app.state.store, app.state.library, app.state.limits = store, library, limits

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError):
        """FastAPI's 422, written as ASCII JSON: the errors quote the input, and an input
        holding a lone surrogate (a JSON \\ud800 escape) cannot be encoded as UTF-8 (the
        default response failed with a 500)."""
        errors = [{**e, "input": shallow(e["input"])} if "input" in e else e
                  for e in exc.errors()]
        text = json.dumps(finite_json({"detail": jsonable_encoder(errors)}),
                          ensure_ascii=True, allow_nan=False)
        return Response(text, status_code=422, media_type="application/json")

    # the token is checked before a body is read (FastAPI reads it before the dependency)
    public = {"/", "/health", app.openapi_url, app.docs_url, app.redoc_url,
              app.swagger_ui_oauth2_redirect_url} - {None}
    app.add_middleware(BodyLimit, max_body=limits.max_body,
                       gate=token_gate(store, public, ("/static/",)))

    def model_or_error(name):
        try:
            return library.get(name)
        except BadName as exc:
            raise HTTPException(422, str(exc)) from None
        except UnknownModel as exc:
            raise HTTPException(404, exc.args[0]) from None

    def own_job(job_id, u):
        job = store.get_job(job_id, user_id=u[0]) if re.fullmatch(r"[0-9a-f]{32}", job_id) \
            else None
        if job is None:
            raise HTTPException(404, f"no job '{job_id}'")
        return job

    # ------------------------------------------------------------------ routes
    @app.get("/health")
    def health():
        r = state["runner"]
        return {"status": "ok", "version": spidersim.__version__,
                "models": len(library.models), "workers": r.n_slots if r else 0}

    @app.get("/models")
    def models_list(u: User):
        out = []
        for n in library.names():
            m = library.models[n]
            try:
                spec = m.spec()
                out.append({"name": n, "title": spec.name,
                            "description": spec.description.strip()})
            except SpidersimError as exc:
                out.append({"name": n, "error": m.public_message(exc)})
        return out

    @app.get("/models/{name}")
    def model_info(name: str, u: User):
        m = model_or_error(name)
        try:
            return m.info()
        except SpidersimError as exc:
            raise HTTPException(422, m.public_message(exc)) from None

    @app.post("/jobs", status_code=202)
    def submit(req: RunRequest, u: User, response: Response,
               idempotency_key: Annotated[Optional[str], Header(max_length=100)] = None):
        m = model_or_error(req.model)
        body = req.model_dump(exclude_none=True)
        try:
            d, t_end = prepare(m, body)
        except SpidersimError as exc:
            raise HTTPException(422, m.public_message(exc)) from None
        if t_end > limits.max_t_end:
            raise HTTPException(422, f"t_end = {t_end:g} s is longer than this service's "
                                     f"limit of {limits.max_t_end:g} s of simulated time")
        n_sig = len(body.get("log") or ())   # a model's own log list is its author's
        if n_sig > limits.max_signals:        # choice; the recording budget bounds its size
            raise HTTPException(422, f"'log' names {n_sig} signals, more than the limit "
                                     f"of {limits.max_signals}: name the signals you need")
        body["t_end"] = t_end
        try:
            job, created = store.create_job(u[0], m.name, body, t_end, spidersim.__version__,
                                            m.file_hash(), idem_key=idempotency_key,
                                            max_active=limits.max_active,
                                            quota=(quota, reserve, since()))
        except KeyReused:
            raise HTTPException(422, "this Idempotency-Key was used for a different request: "
                                     "a key names one request (use a new key for a new "
                                     "request)") from None
        except TooManyJobs as exc:
            raise HTTPException(429, f"you have {exc.n} queued or running jobs, the limit is "
                                     f"{limits.max_active}: wait for one to finish",
                                headers={"Retry-After": "2"}) from None
        except OverQuota as exc:
            raise HTTPException(507, quota_message(
                exc.usage, exc.reserve, exc.limit, store.largest_jobs(u[0], since()),
                limits.keep_days, time.time())) from None
        if state["runner"] is not None:
            state["runner"].wake()
        response.headers["Location"] = f"/jobs/{job['id']}"
        if not created:
            response.status_code = 200
        return _public(job)

    @app.get("/jobs")
    def jobs_list(u: User, limit: int = 100):
        return [_public(j, request=False)
                for j in store.list_jobs(u[0], max(1, min(limit, 1000)), request=False)]

    @app.get("/jobs/{job_id}")
    def job_get(job_id: str, u: User):
        return _public(own_job(job_id, u))

    @app.get("/usage")
    def usage(u: User):
        """The user's disk use against its quota (bytes)."""
        use = store.usage(u[0], since(), reserve)
        return {"user": u[1], "quota_bytes": int(quota), "used_bytes": use["used"],
                "free_bytes": max(0, int(quota) - use["used"]),
                "stored_bytes": use["stored"], "active_jobs": use["active"],
                "reserved_bytes": use["used"] - use["stored"],
                "reserve_per_job_bytes": int(reserve), "keep_days": limits.keep_days,
                "largest": [{"id": jid, "model": model, "bytes": b,
                             "expires": f + keep_s}
                            for jid, model, b, f in store.largest_jobs(u[0], since(), 5)]}

    @app.delete("/jobs/{job_id}")
    def job_delete(job_id: str, u: User):
        """Remove a finished job's files (it stays listed, expired; its result routes
        answer 410); 409 for a queued or running job."""
        job = own_job(job_id, u)
        if job["state"] in ("queued", "running"):
            raise HTTPException(409, f"job {job_id} is {job['state']}: cancel it first "
                                     f"(POST /jobs/{job_id}/cancel), then delete it")
        store.mark_deleted(job_id)
        shutil.rmtree(store.job_dir(job_id), ignore_errors=True)
        return _public(store.get_job(job_id))

    @app.post("/jobs/{job_id}/cancel")
    def job_cancel(job_id: str, u: User):
        job = own_job(job_id, u)
        if job["state"] in ("queued", "running"):
            store.request_cancel(job_id)
            if state["runner"] is not None:
                state["runner"].wake()
        return _public(store.get_job(job_id))

    streams = {}            # user id -> open event streams

    def open_stream(user_id):
        """Count an event stream of the user (429 beyond ``max_streams``); return the
        function that ends it (idempotent)."""
        if streams.get(user_id, 0) >= limits.max_streams:
            raise HTTPException(429, f"you have {streams[user_id]} open event streams, the "
                                     f"limit is {limits.max_streams}: close one (or poll "
                                     f"GET /jobs/{{id}})", headers={"Retry-After": "2"})
        streams[user_id] = streams.get(user_id, 0) + 1
        done = []

        def close():
            if not done:
                done.append(True)
                streams[user_id] -= 1
                if not streams[user_id]:
                    del streams[user_id]
        return close

    @app.get("/jobs/{job_id}/events")
    async def job_events(job_id: str, u: User,
                         authorization: Annotated[Optional[str], Header()] = None):
        """Server-sent events of a job's status until it ends; the token is checked again
        at every poll (a revoked user's open stream ends with an ``error`` event), at most
        ``max_streams`` open per user."""
        own_job(job_id, u)
        token = bearer(authorization)
        close = open_stream(u[0])

        async def stream():
            last = None
            try:
                while True:
                    if store.user_for_token(token) is None:
                        yield ("event: error\ndata: " + dumps_strict(
                            {"detail": "the token is no longer valid (revoked): stream "
                                       "ended"}) + "\n\n")
                        return
                    job = store.get_job(job_id)
                    pub = _public(job, request=False)
                    key = (pub["state"], pub["progress"], pub["message"])
                    if key != last:
                        last = key
                        yield f"event: {pub['state']}\ndata: {dumps_strict(pub)}\n\n"
                    if job["state"] not in ("queued", "running"):
                        return
                    await asyncio.sleep(0.25)
            finally:
                close()

        events = stream()
        weakref.finalize(events, close)       # a stream never started is released too
        return StreamingResponse(events, media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache",
                                          "X-Accel-Buffering": "no"})

    def job_file(job, rel):
        if job["state"] in ("queued", "running") or (job["state"] == "cancelled"
                                                     and not kept_data(job)
                                                     and not expired(job)):
            raise HTTPException(409, f"job {job['id']} is {job['state']}: no results")
        if expired(job):
            raise HTTPException(410, f"the results of job {job['id']} were removed: "
                                     f"deleted by its user, or past the retention time "
                                     f"(this service keeps them {limits.keep_days:g} day(s) "
                                     f"after the job ends)")
        p = os.path.join(store.job_dir(job["id"]), rel)
        if not os.path.isfile(p):
            raise HTTPException(404, f"job {job['id']} has no file {rel}")
        return p

    @app.get("/jobs/{job_id}/result.{ext}")
    def job_result(job_id: str, ext: str, u: User):
        job = own_job(job_id, u)
        names = {"npz": "result.npz", "csv": "result.csv", "txt": "report.txt",
                 "json": "meta.json"}
        if ext not in names:
            raise HTTPException(404, f"results come as result.npz, result.csv, result.txt "
                                     f"(report) or result.json (metadata), not result.{ext}")
        return FileResponse(job_file(job, names[ext]),
                            filename=f"{job['model']}_{job_id[:8]}_{names[ext]}")

    @app.get("/jobs/{job_id}/signals/{name}.json")
    def job_signal(job_id: str, name: str, u: User, stride: int = 1,
                   points: Optional[int] = None):
        job = own_job(job_id, u)
        try:                            # units and sizes, not meta.json's events
            with open(job_file(job, "signals.json")) as fh:
                meta = json.load(fh)
        except HTTPException:           # a job of an earlier version
            with open(job_file(job, "meta.json")) as fh:
                meta = json.load(fh)
        if name not in meta["units"]:
            raise HTTPException(404, f"no logged signal '{name}'; signals: "
                                     f"{', '.join(meta['units'])}")
        npz = job_file(job, "result.npz")
        n, _ = read_rows(npz, "t", None)
        s = max(1, int(stride))
        if points is not None:          # about this many samples, evenly spaced
            s = max(1, -(-n // max(2, int(points))))
        size = int(meta["sizes"][name])
        values = -(-n // s) * size
        if values > limits.max_points:
            need = -(-n * size // limits.max_points)
            raise HTTPException(413, f"signal '{name}' has {n} samples of {size} value(s): "
                                     f"{values} values at stride {s}, more than this "
                                     f"service's limit of {limits.max_points} per answer; "
                                     f"ask for ?stride={need} or ?points="
                                     f"{limits.max_points // size}, or download the whole "
                                     f"record from /jobs/{job_id}/result.npz"
                                     + (" or result.csv" if os.path.isfile(os.path.join(
                                         store.job_dir(job_id), "result.csv")) else ""))
        t = read_rows(npz, "t", s)[1]
        y = read_rows(npz, name, s)[1]
        return {"name": name, "unit": meta["units"][name], "size": size,
                "stride": s, "t": t.tolist(), "values": y.tolist()}

    @app.get("/jobs/{job_id}/plots/{file}")
    def job_plot(job_id: str, file: str, u: User):
        job = own_job(job_id, u)
        if not BARE_NAME.match(file) or not file.endswith((".png", ".gif")):
            raise HTTPException(404, f"no plot '{file}'")
        return FileResponse(job_file(job, os.path.join("plots", file)))

    @app.get("/", include_in_schema=False)
    def page():
        return FileResponse(os.path.join(STATIC, "index.html"))

    app.mount("/static", StaticFiles(directory=STATIC), name="static")
    return app
