"""The request-body limit, enforced on the bytes received (an ASGI middleware).

A limit read from ``Content-Length`` alone was bypassed: h11 frames a request carrying both
``Transfer-Encoding: chunked`` and ``Content-Length`` as chunked, so an anonymous request
announcing 10 bytes sent 2 GB that the app read (the server went from 316 MB to 2.49 GB)
before its token was checked. :class:`BodyLimit` refuses such conflicting framing with 400
before any byte of the body is read, and counts the body as it arrives in the ASGI
receive channel: once over the limit the request is answered 413, whatever its headers.

The token is checked here too, before the body: FastAPI reads a route's body (up to the
limit) before its dependencies run, so an anonymous client could make the server read
``--max-body`` bytes per request only to be told 401. :class:`BodyLimit` takes a ``gate``
(the app's token check) that refuses such a request from its headers.
"""
from __future__ import annotations

import json

from fastapi import HTTPException
from starlette.concurrency import run_in_threadpool

#: methods whose body is read (and limited)
WITH_BODY = ("POST", "PUT", "PATCH")


def framing_error(headers, max_body):
    """``(status, detail)`` refusing a request's body framing from its headers, or None.

    ``headers``: the ASGI scope's list of ``(name, value)`` byte pairs. Both
    ``Transfer-Encoding`` and ``Content-Length`` (RFC 9112 6.1: a request smuggling
    sign), several differing ``Content-Length`` values -> 400; no ``Content-Length`` ->
    411; a non-numeric one or one over ``max_body`` -> 413."""
    te = [v for k, v in headers if k.lower() == b"transfer-encoding"]
    cl = {v.strip() for k, v in headers if k.lower() == b"content-length"}
    if te and cl:
        return 400, ("a request with both Transfer-Encoding and Content-Length is refused "
                     "(conflicting body framing): send Content-Length only")
    if len(cl) > 1:
        return 400, "a request with differing Content-Length headers is refused"
    if not cl:
        return 411, "a request body needs a Content-Length header"
    n = cl.pop().decode("latin-1")
    if not n.isdigit() or int(n) > max_body:
        return 413, too_large(n, max_body)
    return None


def too_large(n, max_body):
    """The 413 detail of a body of ``n`` bytes (a count or a header's text)."""
    return f"request body of {n} bytes is larger than the limit of {max_body} bytes"


async def answer(send, status, detail, headers=()):
    """Send a whole JSON answer ``{"detail": ...}`` with ``status`` (and ``headers``, a list
    of ``(name, value)`` byte pairs)."""
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close"), *headers]})
    await send({"type": "http.response.body", "body": body})


class BodyLimit:
    """ASGI middleware: a request body of at most ``max_body`` bytes.

    The headers are checked first (:func:`framing_error`), then ``gate(scope)`` (run in
    a thread: a token check may hash), which returns None to let the body be read or
    ``(status, detail, headers)`` to refuse the request without reading any of it; then
    the body's bytes are counted as the app receives them, and the first chunk taking the
    count over the limit ends the request with 413 (raised to the app as an
    :class:`HTTPException`, which FastAPI passes on; any answer the app starts afterwards
    is replaced by the 413)."""

    def __init__(self, app, max_body, gate=None):
        self.app, self.max_body, self.gate = app, int(max_body), gate

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or scope["method"] not in WITH_BODY:
            return await self.app(scope, receive, send)
        refusal = framing_error(scope["headers"], self.max_body)
        if refusal is None and self.gate is not None:
            refusal = await run_in_threadpool(self.gate, scope)
        if refusal is not None:
            return await answer(send, *refusal)
        seen = {"bytes": 0, "over": False, "started": False}

        async def counted():
            message = await receive()
            if message["type"] == "http.request" and not seen["over"]:
                seen["bytes"] += len(message.get("body", b""))
                if seen["bytes"] > self.max_body:
                    seen["over"] = True
                    raise HTTPException(413, self.detail(seen["bytes"]))
            return message

        async def guarded(message):
            if message["type"] == "http.response.start":
                seen["started"] = True
                # the app's answer to a body cut short (FastAPI passes the 413 on; an
                # older one answered 400 'error parsing the body'): the 413 instead
                seen["replaced"] = seen["over"] and message["status"] != 413
                if seen["replaced"]:
                    return await answer(send, 413, self.detail(seen["bytes"]))
            if not seen.get("replaced"):
                await send(message)

        try:
            await self.app(scope, counted, guarded)
        except HTTPException as exc:
            if exc.status_code != 413 or not seen["over"] or seen["started"]:
                raise
            await answer(send, 413, exc.detail)

    def detail(self, n):
        """The 413 detail once ``n`` bytes were received."""
        return too_large(f"at least {n}", self.max_body)
