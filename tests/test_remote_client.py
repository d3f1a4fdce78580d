"""The remote client (``spidersim run --remote``, :class:`spidersim.remote.Client`) against
a broken or hostile server: a small fake service (``http.server`` in a thread on a free
loopback port, started and stopped here) whose first URL path segment picks a
misbehaviour. Each one must end in a :class:`~spidersim.remote.RemoteError` (exit status 2
in the CLI) naming what was wrong, write nothing outside ``--out``, leave no partial file,
and take a bounded time; redirects are not followed (the token reaches no other host).
"""
from __future__ import annotations

import io
import json
import os
import re
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import numpy as np
import pytest

from spidersim import remote
from spidersim.cli import main
from spidersim.remote import Client, RemoteError

TOKEN = "tok-test"
PNG = b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 40       # 10,248 bytes, not a real image
T = np.linspace(0.0, 1.0, 11)
X = np.sin(T)


def _npz():
    buf = io.BytesIO()
    np.savez(buf, t=T, x=X)
    return buf.getvalue()


NPZ = _npz()
META = {"sizes": {"x": 1}, "units": {"x": "m"}, "events": [], "stats": {"steps": 10},
        "status": "ok", "message": ""}
CSV = b"t [s],x [m]\n" + b"".join(b"%r,%r\n" % (a, b) for a, b in zip(T, X))

#: the files each mode's job lists (mode "abs" gets an absolute path at start-up)
LISTINGS = {
    "ok": {"data": ["result.npz", "result.csv"], "plots": ["position.png", "arm.gif"]},
    "rel": {"data": [], "plots": ["../../escaped.png"]},
    "sub": {"data": [], "plots": ["sub/escaped.png"]},
    "dotdot": {"data": [], "plots": [".."]},
    "dot": {"data": [], "plots": ["."]},
    "hidden": {"data": [], "plots": [".bashrc.png"]},
    "nul": {"data": [], "plots": ["a\x00b.png"]},
    "backslash": {"data": [], "plots": ["..\\..\\escaped.png"]},
    "long": {"data": [], "plots": ["a" * 200 + ".png"]},
    "nonstr": {"data": [], "plots": [7]},
    "twice": {"data": [], "plots": ["p.png", "p.png"]},
    "notplot": {"data": [], "plots": ["run.sh"]},
    "baddata": {"data": ["evil.bin"], "plots": []},
    "hugeplot": {"data": ["result.csv"], "plots": ["big.png"]},
    "streamplot": {"data": [], "plots": ["big.png"]},
    "three": {"data": [], "plots": ["a.png", "b.png", "c.png"]},
    "dripplot": {"data": [], "plots": ["slow.png"]},
}

def _gzip_bomb(mib):
    """``mib`` MiB of spaces (JSON whitespace) gzipped twice: a few KB on the wire."""
    import gzip
    import zlib
    co = zlib.compressobj(9, zlib.DEFLATED, 31)
    inner = b"".join(co.compress(b" " * 2**20) for _ in range(mib)) + co.flush()
    return gzip.compress(inner, 9)


GZIP_BOMB = _gzip_bomb(64)
DRIP_LIMIT = 8.0        # s a dripping answer lasts at most (then the fake server hangs up)


class _Fake(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"

    def log_message(self, *a):
        pass

    def send(self, code, body=b"", ctype="application/json", extra=()):
        body = body.encode() if isinstance(body, str) else body
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        for k, v in extra:
            self.send_header(k, v)
        self.end_headers()
        self.wfile.write(body)

    def drip(self, data, interval=0.2):
        """``data`` one byte every ``interval`` s until the client hangs up or DRIP_LIMIT."""
        t0 = time.monotonic()
        try:
            for b in data:
                if self.server.stop.is_set() or time.monotonic() - t0 > DRIP_LIMIT:
                    break
                self.wfile.write(bytes([b]))
                self.wfile.flush()
                time.sleep(interval)
        except OSError:
            pass
        self.close_connection = True

    def status(self, mode):
        files = LISTINGS.get(mode, LISTINGS["ok"])
        if mode == "abs":
            files = {"data": [], "plots": [self.server.abs_target]}
        st = {"id": "j1", "state": "done", "progress": 1.0, "t_end": 1.0, "message": "",
              "files": files}
        if mode == "nostate":
            del st["state"]
        elif mode == "nullfiles":
            st["files"] = None
        elif mode == "strprogress":
            st["progress"] = "x"
        elif mode == "running":
            st["state"] = "running"
            st["progress"] = 0.25
        elif mode == "nanprogress":
            return json.dumps(st).replace('"progress": 1.0', '"progress": NaN')
        return json.dumps(st)

    def handle_any(self):
        self.server.seen.append((self.command, self.path, self.headers.get("Authorization")))
        n = int(self.headers.get("Content-Length") or 0)
        if n:
            self.rfile.read(n)
        parts = self.path.split("?")[0].strip("/").split("/")
        mode, rest = parts[0], "/".join(parts[1:])
        if mode == "badjson":
            return self.send(200, "{not json")
        if mode in ("gzip", "gzip500"):      # a gzip bomb the client did not ask for
            return self.send(200 if mode == "gzip" else 500, GZIP_BOMB,
                             extra=[("Content-Encoding", "gzip, gzip")])
        if mode == "identity" and rest == "jobs/j1":
            return self.send(200, self.status("ok"), extra=[("Content-Encoding", "identity")])
        if mode == "redirect":
            return self.send(302, extra=[("Location", f"{self.server.other}/ok/{rest}")])
        if mode == "code204":
            return self.send(204)
        if mode == "html500":
            return self.send(500, "<html>" + "x" * 100 + "</html>", "text/html")
        if mode == "driphead" and rest == "jobs/j1":
            self.wfile.write(b"HTTP/1.1 200 OK\r\n")
            return self.drip(b"Content-Type: application/json\r\n" * 100)
        if mode == "drip" and rest == "jobs/j1" or mode == "dripplot" and "plots/" in rest:
            self.send_response(200)
            self.send_header("Content-Length", "1000000")
            self.end_headers()
            return self.drip(b" " * 1000000)
        if mode == "hugeplot" and rest.startswith("jobs/j1/plots/"):
            self.send_response(200)         # announces 800 MiB, sends 1 MiB and hangs up
            self.send_header("Content-Type", "image/png")
            self.send_header("Content-Length", str(800 * 2**20))
            self.end_headers()
            try:
                self.wfile.write(b"\0" * 2**20)
            except OSError:
                pass
            self.close_connection = True
            return None
        if mode == "streamplot" and rest.startswith("jobs/j1/plots/"):
            self.send_response(200)         # no length: the body ends when the server closes
            self.send_header("Content-Type", "image/png")
            self.send_header("Connection", "close")
            self.end_headers()
            try:
                self.wfile.write(b"\1" * self.server.stream_bytes)
            except OSError:
                pass
            self.close_connection = True
            return None
        if rest == "jobs" and self.command == "POST":
            return self.send(200, {"listjson": "[1, 2]",
                                   "badid": '{"id": "../../models"}'}.get(mode, '{"id": "j1"}'))
        if rest == "jobs/j1":
            return self.send(200, "[1, 2]" if mode == "statuslist" else self.status(mode))
        if rest == "jobs/j1/result.json":
            return self.send(200, "[]" if mode == "listmeta" else json.dumps(META))
        if rest == "jobs/j1/result.npz":
            return self.send(200, b"not an npz" if mode == "badnpz" else NPZ,
                             "application/octet-stream")
        if rest == "jobs/j1/result.csv":
            return self.send(200, CSV, "text/csv")
        if rest.startswith("jobs/j1/signals/"):
            return self.send(200, '{"t": "no list"}' if mode == "badsignal"
                             else '{"t": [0], "values": [1], "unit": "m"}')
        if rest.startswith("jobs/j1/plots/"):
            return self.send(200, PNG, "image/png")
        if rest == "models":
            return self.send(200, '{"a": 1}' if mode == "dictmodels" else '[]')
        return self.send(404, json.dumps({"detail": "no such path"}))

    do_GET = do_POST = handle_any


def _start(host):
    srv = ThreadingHTTPServer((host, 0), _Fake)
    srv.daemon_threads = True
    srv.stop = threading.Event()
    srv.seen = []
    srv.stream_bytes = 0
    threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05},
                     daemon=True).start()
    return srv


@pytest.fixture(scope="module")
def fake(tmp_path_factory):
    """The fake service on 127.0.0.1 and a second one on another loopback address (the
    target of the redirect, which must never be asked); both stopped at the end."""
    try:
        other = _start("127.0.0.2")
    except OSError:                     # no 127.0.0.2 here: another port of 127.0.0.1
        other = _start("127.0.0.1")
    srv = _start("127.0.0.1")
    srv.other = f"http://{other.server_address[0]}:{other.server_address[1]}"
    srv.url = f"http://127.0.0.1:{srv.server_address[1]}"
    srv.abs_target = str(tmp_path_factory.mktemp("abs") / "escaped_abs.png")
    srv.other_srv = other
    yield srv
    for s in (srv, other):
        s.stop.set()
        s.shutdown()
        s.server_close()


def _files_under(root):
    return {os.path.join(d, f) for d, _, fs in os.walk(root) for f in fs}


def run_remote(fake, mode, tmp_path, capsys, *extra):
    """``spidersim run servo --remote URL/MODE --out tmp/a/b/out``: exit code, stderr,
    seconds taken, the out folder."""
    out = tmp_path / "a" / "b" / "out"
    t0 = time.monotonic()
    rc = main(["run", "servo", "--remote", f"{fake.url}/{mode}", "--token", TOKEN,
               "--out", str(out), *extra])
    dt = time.monotonic() - t0
    return rc, capsys.readouterr().err, dt, out


# mode, words of the message, extra CLI options
CASES = [
    ("rel", ["not a bare file name", "../../escaped.png", "nothing written"], []),
    ("abs", ["not a bare file name", "escaped_abs.png"], []),
    ("sub", ["not a bare file name", "sub/escaped.png"], []),
    ("dotdot", ["not a bare file name", "'..'"], []),
    ("dot", ["not a bare file name", "'.'"], []),
    ("hidden", ["not a bare file name", ".bashrc.png"], []),
    ("nul", ["not a bare file name", "a\\x00b.png"], []),
    ("backslash", ["not a bare file name"], []),
    ("long", ["not a bare file name", "at most 121"], []),
    ("nonstr", ["not a bare file name", "7"], []),
    ("twice", ["listed twice", "p.png"], []),
    ("notplot", ["run.sh", "not a .png or .gif"], []),
    ("baddata", ["evil.bin", "not one of result.npz"], []),
    ("badjson", ["/badjson/jobs", "not JSON", "{not json"], []),
    ("listjson", ["/listjson/jobs", "a list where the new job"], []),
    ("statuslist", ["/statuslist/jobs/j1", "a list where the job's status"], []),
    ("nostate", ["/nostate/jobs/j1", "no valid 'state'", "null"], []),
    ("nullfiles", ["/nullfiles/jobs/j1", "'files' is null"], []),
    ("strprogress", ["/strprogress/jobs/j1", "'progress' is a text 'x'"], []),
    ("nanprogress", ["/nanprogress/jobs/j1", "'progress'", "not a finite number"], []),
    ("code204", ["/code204/jobs", "an empty answer (HTTP 204)"], []),
    ("html500", ["/html500/jobs", "HTTP 500"], []),
    ("badid", ["job id", "../../models"], []),
    ("redirect", ["HTTP 302", "a redirect to", "not followed"], []),
    ("running", ["job j1 still running after 1 s", "t = 0.25 / 1 s"], ["--timeout", "1"]),
    # --timeout bounds submitting and waiting together (one deadline over their requests)
    ("drip", ["/drip/jobs/j1", "no complete answer within", "too slow or stalls"],
     ["--timeout", "2"]),
    ("driphead", ["/driphead/jobs/j1", "no complete answer within"], ["--timeout", "2"]),
    ("hugeplot", ["/hugeplot/jobs/j1/plots/big.png", "announces 800 MiB", "64 MiB",
                  "max_plot_bytes", "not read"], []),
]


@pytest.mark.parametrize("mode, words, extra", CASES, ids=[c[0] for c in CASES])
def test_cli_refuses_a_misbehaving_server(fake, mode, words, extra, tmp_path, capsys):
    """Each misbehaviour of the fake server ends in exit status 2 (a RemoteError, not
    'internal error' 3) with a message naming the URL or the name and what was wrong;
    nothing is written outside --out (traversal names: not even inside it), no partial
    file is left, and the run ends in bounded time: a few seconds, or --timeout plus
    at most 1.5 s for a server that drips its answer (the drip lasts DRIP_LIMIT = 8 s)."""
    rc, err, dt, out = run_remote(fake, mode, tmp_path, capsys, *extra)
    assert rc == 2, err
    assert "internal error" not in err and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)
    outside = {p for p in _files_under(tmp_path) if not p.startswith(str(out) + os.sep)}
    assert outside == set(), outside
    assert not os.path.exists(fake.abs_target)
    inside = {os.path.basename(p) for p in _files_under(out)}
    assert not any(n.endswith(".part") for n in inside), inside
    if mode == "hugeplot":                   # the data file before it is complete, kept
        assert inside == {"result.csv"} and (out / "result.csv").read_bytes() == CSV
    elif mode not in ("running", "drip", "driphead"):
        assert inside == set(), inside
    limit = float(extra[1]) + 1.5 if extra else 5.0
    assert dt < limit, (dt, err)
    if extra:                                # it waited the time it was given
        assert dt >= float(extra[1]), dt


def test_cli_invalid_url_is_exit_2(tmp_path, capsys):
    """A URL httpx cannot parse (``http://[::1``, was InvalidURL, exit 3) or that is no
    http(s) service: exit status 2 naming the URL."""
    for url in ("http://[::1", "ftp://example.org", "localhost:8050", "http://h/?q=1"):
        rc = main(["run", "servo", "--remote", url, "--token", TOKEN,
                   "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err
        assert rc == 2 and "not a service URL" in err and url in err, err
    assert not (tmp_path / "out").exists()


def test_cli_out_naming_a_file_is_refused_before_submitting(fake, tmp_path, capsys):
    """--out naming an existing file: exit 2 naming it, and no job is submitted (the
    job ran on the service, then the download failed); the file is unchanged."""
    fake.seen.clear()
    f = tmp_path / "taken"
    f.write_text("mine")
    rc = main(["run", "servo", "--remote", f"{fake.url}/ok", "--token", TOKEN,
               "--out", str(f)])
    err = capsys.readouterr().err
    assert rc == 2 and str(f) in err and "not a folder" in err, err
    assert fake.seen == [] and f.read_text() == "mine"


@pytest.mark.parametrize("file", ["/local/path/m1.yaml", "m1.yaml", "m1.YML", "lib/m1"])
def test_cli_remote_refuses_a_local_path(fake, file, tmp_path, capsys):
    """A path (a '/' or a .yaml/.yml name) with --remote is refused, saying the service
    runs its own models by name; it ran the service's model of that base name."""
    fake.seen.clear()
    rc = main(["run", file, "--remote", f"{fake.url}/ok", "--token", TOKEN,
               "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and f"'{file}' is a file path" in err and "by name" in err, err
    assert fake.seen == [] and not (tmp_path / "out").exists()


def test_cli_remote_without_a_model_name_is_refused(fake, tmp_path, capsys):
    rc = main(["run", "--remote", f"{fake.url}/ok", "--token", TOKEN])
    err = capsys.readouterr().err
    assert rc == 2 and "give the NAME of a model" in err and "Traceback" not in err, err


def test_redirect_is_not_followed_and_the_token_stays(fake, tmp_path, capsys):
    """A redirect to another host is an error, and that host receives no request (so
    never the token); the fake server itself saw the token."""
    fake.other_srv.seen.clear()
    rc, err, _, _ = run_remote(fake, "redirect", tmp_path, capsys)
    assert rc == 2 and fake.url in err and fake.other in err, err
    assert fake.other_srv.seen == []
    assert ("POST", "/redirect/jobs", f"Bearer {TOKEN}") in fake.seen


def test_cli_ok_server_downloads_exact_bytes(fake, tmp_path, capsys):
    """A well-behaved server: exit 0, every listed file written byte for byte as served
    (streamed through a .part file), no other file."""
    rc, err, _, out = run_remote(fake, "ok", tmp_path, capsys)
    assert rc == 0, err
    assert {os.path.basename(p) for p in _files_under(out)} == {
        "result.npz", "result.csv", "position.png", "arm.gif"}
    assert (out / "result.npz").read_bytes() == NPZ
    assert (out / "result.csv").read_bytes() == CSV
    assert (out / "position.png").read_bytes() == PNG == (out / "arm.gif").read_bytes()
    assert _files_under(tmp_path) == _files_under(out)


def test_cli_drip_during_download_is_cut_by_the_request_timeout(fake, tmp_path, capsys,
                                                                monkeypatch):
    """A plot that drips one byte every 0.2 s (httpx's read timeout never fires) is cut
    off at the per-request deadline (REQUEST_TIMEOUT, here 1.5 s), not after the whole
    body; the partial file is removed."""
    monkeypatch.setattr(remote, "REQUEST_TIMEOUT", 1.5)
    rc, err, dt, out = run_remote(fake, "dripplot", tmp_path, capsys)
    assert rc == 2 and "/dripplot/jobs/j1/plots/slow.png" in err, err
    assert "no complete answer within 1.5 s" in err, err
    assert 1.5 <= dt < 3.5, dt
    assert _files_under(out) == set()


@pytest.mark.parametrize("cap, sent, ok", [(2**20, 2**20, True), (2**20, 2**20 + 1, False)])
def test_plot_size_cap_is_exact_for_an_unannounced_length(fake, tmp_path, cap, sent, ok):
    """A plot without Content-Length (the body ends when the server closes): exactly the
    cap is accepted, one byte more is refused while streaming, and the refused file
    leaves nothing (no plot, no .part) in the folder."""
    fake.stream_bytes = sent
    with Client(f"{fake.url}/streamplot", TOKEN, max_plot_bytes=cap) as c:
        if ok:
            paths = c.download("j1", str(tmp_path))
            assert [os.path.basename(p) for p in paths] == ["big.png"]
            assert os.path.getsize(paths[0]) == sent
        else:
            with pytest.raises(RemoteError) as e:
                c.download("j1", str(tmp_path))
            assert "longer than the 1 MiB" in str(e.value) and "max_plot_bytes" in str(e.value)
            assert os.listdir(tmp_path) == []


def test_total_download_cap(fake, tmp_path):
    """Three plots of 10,248 bytes under a total cap of 25,000 bytes: the first two are
    written, the third is refused naming the total limit, no partial file remains."""
    with Client(f"{fake.url}/three", TOKEN, max_total_bytes=25_000) as c:
        with pytest.raises(RemoteError) as e:
            c.download("j1", str(tmp_path))
    assert "left of the 24.41 KiB" in str(e.value) and "max_total_bytes" in str(e.value)
    assert sorted(os.listdir(tmp_path)) == ["a.png", "b.png"]


def test_python_client_raises_remote_error(fake):
    """The Python Client's calls on broken answers raise RemoteError (not JSONDecodeError,
    TypeError, KeyError, ValueError): result() with a list as metadata or an npz that is
    not one, signal() without lists, models() given an object, status() of a dripping
    server (bounded by Client(timeout)), and a job id that is not one (no request made)."""
    cases = [("badjson", lambda c: c.result("j1"), "not JSON"),
             ("listmeta", lambda c: c.result("j1"), "a list where the job's metadata"),
             ("badnpz", lambda c: c.result("j1"), "do not make a result"),
             ("nostate", lambda c: c.result("j1"), "no valid 'state'"),
             ("badjson", lambda c: c.signal("j1", "x"), "not JSON"),
             ("badsignal", lambda c: c.signal("j1", "x"), "no lists 't' and 'values'"),
             ("code204", lambda c: c.signal("j1", "x"), "an empty answer"),
             ("dictmodels", lambda c: c.models(), "an object where the list of models"),
             ("redirect", lambda c: c.models(), "not followed"),
             ("ok", lambda c: c.status("../models"), "not a job id")]
    for mode, call, words in cases:
        with Client(f"{fake.url}/{mode}", TOKEN) as c:
            with pytest.raises(RemoteError) as e:
                call(c)
            assert words in str(e.value), (mode, str(e.value))
    n = len(fake.seen)
    with Client(f"{fake.url}/ok", TOKEN) as c, pytest.raises(RemoteError):
        c.result("a/../../b")
    assert len(fake.seen) == n
    t0 = time.monotonic()
    with Client(f"{fake.url}/drip", TOKEN, timeout=1.0) as c, pytest.raises(RemoteError) as e:
        c.status("j1")
    assert 1.0 <= time.monotonic() - t0 < 2.5 and "within 1 s" in str(e.value)


def test_python_client_result_and_deadline(fake):
    """A good answer still makes the Result (t and x equal to what the server holds);
    Client.deadline bounds a sequence of calls: inside a 1 s deadline a dripping status
    call is cut at 1 s although one request may take 30 s."""
    with Client(f"{fake.url}/ok", TOKEN) as c:
        r = c.result("j1")
        assert np.array_equal(r.t, T) and np.array_equal(r["x"], X) and r.units["x"] == "m"
    with Client(f"{fake.url}/drip", TOKEN) as c:
        t0 = time.monotonic()
        with c.deadline(1.0), pytest.raises(RemoteError) as e:
            c.status("j1")
        # the message gives what was left of the deadline when the request began: 1 s, or
        # a hair less on a loaded machine (0.999 s)
        assert 1.0 <= time.monotonic() - t0 < 2.5
        assert re.search(r"within (1|0\.9\d*) s", str(e.value)), str(e.value)


def test_client_rejects_bad_options():
    """Client options: a bad timeout or limit is refused naming it."""
    for kw, name in (({"timeout": 0}, "timeout"), ({"timeout": float("nan")}, "timeout"),
                     ({"max_plot_bytes": -1}, "max_plot_bytes")):
        with pytest.raises(remote.SpidersimError) as e:
            Client("http://127.0.0.1:9", TOKEN, **kw)
        assert name in str(e.value)



@pytest.mark.parametrize("mode, words", [
    ("gzip", ["/gzip/jobs/j1", "encoded 'gzip, gzip'", "Accept-Encoding: identity",
              "not read"]),
    ("gzip500", ["/gzip500/jobs/j1", "HTTP 500", "encoded 'gzip, gzip'"])])
def test_an_encoding_not_asked_for_is_refused_undecoded(fake, mode, words):
    """``Content-Encoding: gzip, gzip`` (a few KB decoding to 64 MiB here; 1 GiB took the
    client to 3.28 GB, the size limit counting decoded bytes): a RemoteError naming the
    encoding, nothing decoded (the peak of Python allocations stays far below 64 MiB);
    an error answer too. An answer marked ``identity`` is read."""
    import tracemalloc
    assert len(GZIP_BOMB) < 100_000
    with Client(f"{fake.url}/{mode}", TOKEN) as c:
        tracemalloc.start()
        try:
            with pytest.raises(RemoteError) as e:
                c.status("j1")
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    for w in words:
        assert w in str(e.value), str(e.value)
    assert peak < 8 * 2**20, f"{peak / 2**20:.0f} MiB allocated"
    with Client(f"{fake.url}/identity", TOKEN) as c:
        assert c.status("j1")["state"] == "done"
