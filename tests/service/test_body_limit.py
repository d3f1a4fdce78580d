"""The request-body limit against a body larger than its headers say (the security review:
``Transfer-Encoding: chunked`` with a ``Content-Length`` of 10 made h11 read a chunked body
of any size, before the token check: an anonymous request took the server from 316 MB to
2.49 GB). Conflicting framing is a 400 before any body byte is read; the bytes received
are counted whatever the headers (413 once over the limit)."""
from __future__ import annotations

import asyncio
import json
import re
import select
import socket
import threading
import time

import psutil
import pytest

from spidersim.service.app import Limits, create_app
from spidersim.service.body import BodyLimit

from .conftest import SERVO


def read_answer(s):
    """The whole HTTP answer on socket ``s``: its head, then its ``Content-Length`` bytes
    or up to the end (one ``recv`` could return the head alone, a flaky failure)."""
    text = b""
    while True:
        head, sep, body = text.partition(b"\r\n\r\n")
        if sep:
            n = re.search(rb"(?im)^content-length: *(\d+)", head)
            if n and len(body) >= int(n.group(1)):
                return text.decode("latin-1")
        got = s.recv(4096)
        if not got:
            return text.decode("latin-1")
        text += got


def post_chunked(server, token, mb, content_length="10"):
    """POST /jobs with both ``Transfer-Encoding: chunked`` and ``Content-Length``, then
    up to ``mb`` MiB of chunks (sent by a thread while the answer is read); return
    ``(status line, answer text, seconds, MiB sent)``."""
    s = socket.create_connection(("127.0.0.1", server.port))
    auth = f"Authorization: Bearer {token}\r\n" if token else ""
    s.sendall((f"POST /jobs HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n{auth}"
               f"Content-Length: {content_length}\r\nTransfer-Encoding: chunked\r\n\r\n"
               ).encode())
    sent = [-1]

    def pour():
        pad = b" " * (1 << 20)
        try:
            for part in [b'{"model":"servo","t_end":0.1'] + [pad] * mb:
                s.sendall(b"%x\r\n" % len(part) + part + b"\r\n")
                sent[0] += 1
            s.sendall(b"1\r\n}\r\n0\r\n\r\n")
        except OSError:
            pass
    t0 = time.time()
    th = threading.Thread(target=pour, daemon=True)
    th.start()
    s.settimeout(30)
    try:
        text = read_answer(s)
    finally:
        dt = time.time() - t0
        s.close()
        th.join(30)
    return text.split("\r\n", 1)[0], text, dt, sent[0]


@pytest.mark.parametrize("who", ["alice", None])
def test_chunked_body_with_content_length_is_400_without_reading(server, who):
    """A token holder and an anonymous client: 400 in well under a second, the server's
    memory unchanged (it grew by the body's size before), the 200 MiB mostly unsent."""
    proc = psutil.Process(server.proc.pid)
    before = proc.memory_info().rss
    status, text, dt, sent = post_chunked(server, getattr(server, who) if who else None, 200)
    grown = proc.memory_info().rss - before
    assert " 400 " in status, text
    assert "both Transfer-Encoding and Content-Length" in text
    assert dt < 5 and sent < 200
    assert grown < 20e6, f"the server grew by {grown / 1e6:.0f} MB"
    # the server still serves
    assert server.client(server.alice).get("/jobs").status_code == 200


def drive(app, headers, chunks):
    """Run ``app`` on one POST /jobs whose receive channel yields ``chunks`` (bytes) then
    waits; return ``(status, detail, chunks consumed)``."""
    sent, got = [0], []

    async def receive():
        if sent[0] < len(chunks):
            sent[0] += 1
            return {"type": "http.request", "body": chunks[sent[0] - 1], "more_body": True}
        await asyncio.sleep(3600)

    async def send(message):
        got.append(message)

    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1",
             "method": "POST", "scheme": "http", "path": "/jobs", "raw_path": b"/jobs",
             "query_string": b"", "root_path": "", "headers": headers,
             "client": ("127.0.0.1", 1), "server": ("127.0.0.1", 80)}
    asyncio.run(asyncio.wait_for(app(scope, receive, send), 30))
    start = next(m for m in got if m["type"] == "http.response.start")
    body = b"".join(m.get("body", b"") for m in got if m["type"] == "http.response.body")
    return start["status"], json.loads(body)["detail"], sent[0]


def test_body_bytes_are_counted_whatever_the_headers(tmp_path):
    """A body larger than its Content-Length (a server framing it otherwise) is cut at the
    limit: 413 after the first chunk over it, the rest never read."""
    from spidersim.service.store import Store
    tok = Store(str(tmp_path)).add_user("eve")
    app = create_app(str(tmp_path), [SERVO], None, Limits(max_body=5000))
    chunks = [b'{"model":"servo"'] + [b" " * 1000] * 1000
    headers = [(b"content-type", b"application/json"), (b"content-length", b"10"),
               (b"authorization", f"Bearer {tok}".encode())]
    status, detail, used = drive(app, headers, chunks)
    assert status == 413, detail
    assert "limit of 5000 bytes" in detail
    assert used == 6            # 16 + 5 x 1000 bytes: the chunk taking it over 5000
    # the middleware without a gate, before the app: the same at its own limit
    status, detail, used = drive(BodyLimit(app, 2000), headers, chunks)
    assert (status, used) == (413, 3)


@pytest.mark.parametrize("auth", [None, "Bearer sst_nosuch_token", "Basic ZXZlOng=",
                                  "Bearer "])
def test_no_valid_token_is_401_before_any_body_byte(tmp_path, auth):
    """Without a valid token a POST is refused from its headers: no chunk of its body is
    consumed (FastAPI read the body, up to the limit, before the token dependency ran)."""
    app = create_app(str(tmp_path), [SERVO], None, Limits(max_body=5000))
    headers = [(b"content-type", b"application/json"), (b"content-length", b"4000")]
    if auth is not None:
        headers.append((b"authorization", auth.encode()))
    status, detail, used = drive(app, headers, [b'{"model":"servo"'] + [b" " * 100] * 50)
    assert (status, used) == (401, 0), detail
    assert detail.startswith("a valid token is required")


def test_public_routes_need_no_token(tmp_path):
    """The page, its static files, /health and the API description answer as before
    without a token; a POST to them is still 405, not 401."""
    from fastapi.testclient import TestClient
    app = create_app(str(tmp_path), [SERVO], None, Limits())
    with TestClient(app) as c:
        for path in ("/", "/health", "/static/app.js", "/openapi.json", "/docs"):
            assert c.get(path).status_code == 200, path
        assert c.post("/health", content=b"{}").status_code == 405
        assert c.post("/static/app.js", content=b"{}").status_code == 405
        r = c.post("/jobs", json={"model": "servo"})
        assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
        assert c.post("/no/such/route", content=b"{}").status_code == 401


def stream_post(port, token, size, piece=1024, first_wait=2.0):
    """POST /jobs announcing ``size`` bytes, sent ``piece`` bytes at a time only while no
    answer has arrived (``first_wait`` s allowed before the first piece); return
    ``(status code, body bytes sent, answer text)``."""
    head = b'{"model":"nosuch","t_end":0.1'
    body_sent = 0
    with socket.create_connection(("127.0.0.1", port)) as s:
        auth = f"Authorization: Bearer {token}\r\n" if token else ""
        s.sendall((f"POST /jobs HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                   f"{auth}Content-Length: {size}\r\nConnection: close\r\n\r\n").encode())
        wait = first_wait
        while body_sent < size:
            if select.select([s], [], [], wait)[0]:
                break                                   # the server answered
            wait = 0
            part = (head if body_sent == 0 else b"") + b" " * piece
            part = part[:size - body_sent - 1] + (b"}" if body_sent + len(part) >= size - 1
                                                 else b"")
            try:
                s.sendall(part)
            except OSError:
                break
            body_sent += len(part)
        s.settimeout(30)
        text = read_answer(s)
    return int(text.split(" ", 2)[1]), body_sent, text


def test_anonymous_streaming_body_refused_after_a_few_kb(tmp_path, models_dir):
    """Over loopback, against a server taking bodies of 8 MB: an anonymous POST /jobs and
    one with a wrong token announcing 8 MB are answered 401 with at most a few KB of the
    body sent (the client sends each KB only while no answer has come); with a valid token
    the same request is read whole (the method counts what the server reads: 404, no
    model 'nosuch'). Before the fix the anonymous request was read whole too."""
    from .conftest import Server, add_user
    data = tmp_path / "data"
    srv = Server(data, models_dir, ["--workers", "1", "--max-body", "8000000"])
    tok = add_user(data, "erin")
    srv.start()
    try:
        for token in (None, "sst_nosuch_token"):
            status, sent, text = stream_post(srv.port, token, 8_000_000)
            assert status == 401, text
            assert sent <= 4096, f"{sent} body bytes sent before the 401"
        status, sent, text = stream_post(srv.port, tok, 8_000_000)
        assert status == 404 and "nosuch" in text, text
        assert sent == 8_000_000
    finally:
        srv.stop()


def test_headers_refused_before_the_body():
    """Conflicting or missing framing is refused from the headers alone."""
    from spidersim.service.body import framing_error
    cl, te = (b"content-length", b"10"), (b"transfer-encoding", b"chunked")
    assert framing_error([cl, te], 100)[0] == 400
    assert framing_error([te, (b"Content-Length", b"10")], 100)[0] == 400
    assert framing_error([cl, (b"content-length", b"11")], 100)[0] == 400
    assert framing_error([te], 100)[0] == 411
    assert framing_error([(b"content-length", b"101")], 100)[0] == 413
    assert framing_error([(b"content-length", b"-1")], 100)[0] == 413
    assert framing_error([cl, cl], 100) is None
