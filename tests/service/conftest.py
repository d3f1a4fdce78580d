"""Fixtures: the real service (``spidersim serve``) in a subprocess on a free loopback port,
with a fresh data folder, and users made with ``spidersim serve --add-user``.

Models: ``diagrams/servo.yaml`` (short runs), ``slow.yaml`` written here: a lightly
damped second-order system under a sine, with a small max_step, so that a run takes long
enough to be cancelled, killed or interrupted by a server restart, and ``trajectory.yaml``:
a QuinticProfile integrated, for the ``joint_path`` command.
"""
from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time

import httpx
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SERVO = os.path.join(ROOT, "diagrams", "servo.yaml")

SLOW = """\
name: slow
description: A lightly damped oscillator under a sine, many small steps (test model).
blocks:
  u:   {type: Sine, amplitude: 1, f: 3}
  sys: {type: TransferFunction, num: [1], den: [1, 0.2, 100]}
connections:
  - u.y -> sys.u
simulation: {t_end: 1000, max_step: 2e-4}
log: [u.y, sys.y]
"""

TRAJECTORY = """\
name: trajectory
description: A joint reference (QuinticProfile) and its integral (test model).
blocks:
  ref: {type: QuinticProfile, q0: 0, q1: 1, T: 1}
  acc: {type: Integrator}
connections:
  - ref.q -> acc.u
simulation: {t_end: 2}
log: [ref.q, ref.qd, acc.y]
"""


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cli(*args, check=True):
    p = subprocess.run([sys.executable, "-m", "spidersim.cli", *args], capture_output=True,
                       text=True, timeout=120)
    if check and p.returncode != 0:
        raise AssertionError(f"spidersim {' '.join(args)} failed: {p.stderr}")
    return p


def add_user(data, name, process=False):
    """``spidersim serve --add-user NAME --data DATA``; return the token it prints.

    By default the command runs in this process (:func:`spidersim.cli.main`, the same
    argument parsing and code as the console command, stdout captured): a process per user
    cost about 2.5 s of CPU for importing spidersim, and the service tests made nine.
    ``process=True`` runs the real console command in a fresh process (the module server's
    first user does, so that the command as a user types it stays tested)."""
    if process:
        out = cli("serve", "--add-user", name, "--data", str(data)).stdout
    else:
        import contextlib
        import io

        from spidersim.cli import main
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            rc = main(["serve", "--add-user", name, "--data", str(data)])
        out = buf.getvalue()
        assert rc == 0, out
    m = re.search(r"(sst_\S+)", out)
    assert m, out
    return m.group(1)


class Server:
    """One ``spidersim serve`` process; ``restart()`` keeps the data folder."""

    def __init__(self, data, models, extra=(), new_session=False):
        """``new_session``: the server leads its own process group (as under systemd),
        so that a test can signal the whole group."""
        self.data, self.models, self.extra = str(data), models, list(extra)
        self.new_session = new_session
        self.proc = None
        self.log = os.path.join(self.data, "server.log")

    def start(self):
        os.makedirs(self.data, exist_ok=True)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        args = [sys.executable, "-m", "spidersim.cli", "serve", "--port", str(self.port),
                "--data", self.data]
        for m in self.models:
            args += ["--models", m]
        self._fh = open(self.log, "a")
        self.proc = subprocess.Popen(args + self.extra, stdout=self._fh,
                                     stderr=subprocess.STDOUT,
                                     start_new_session=self.new_session)
        t0 = time.time()
        while time.time() - t0 < 60:
            if self.proc.poll() is not None:
                raise AssertionError("server exited: " + open(self.log).read()[-3000:])
            try:
                if httpx.get(self.url + "/health", timeout=1).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise AssertionError("server did not start: " + open(self.log).read()[-3000:])

    def kill(self):
        """SIGKILL the server (no clean-up: a crash)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)

    def stop(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.kill()
        self._fh.close()

    def workers(self):
        """pids of the server's worker processes."""
        import psutil
        try:
            kids = psutil.Process(self.proc.pid).children()
        except psutil.NoSuchProcess:
            return []
        return [k.pid for k in kids if "resource_tracker" not in " ".join(k.cmdline())]

    def client(self, token):
        return httpx.Client(base_url=self.url, timeout=30,
                            headers={"Authorization": f"Bearer {token}"} if token else {})


@pytest.fixture(scope="session")
def models_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("models")
    (d / "slow.yaml").write_text(SLOW)
    (d / "trajectory.yaml").write_text(TRAJECTORY)
    return [SERVO, str(d)]


@pytest.fixture(scope="module")
def server(tmp_path_factory, models_dir):
    data = tmp_path_factory.mktemp("data")
    s = Server(data, models_dir, ["--workers", "2", "--max-jobs", "3", "--max-t-end", "1000",
                                  "--max-signals", "5", "--max-body", "20000"])
    s.alice = add_user(data, "alice", process=True)
    s.bob = add_user(data, "bob")
    s.start()
    yield s
    s.stop()


def wait_progress(http, job, above=0.0, timeout=60):
    """The job once its run has passed ``t = above`` [s] (or it has ended)."""
    t0 = time.time()
    while True:
        j = http.get(f"/jobs/{job}").json()
        if j["progress"] > above or j["state"] not in ("queued", "running"):
            return j
        assert time.time() - t0 < timeout, j
        time.sleep(0.05)


def wait_state(http, job, states=("done", "failed", "cancelled"), timeout=120):
    t0 = time.time()
    while time.time() - t0 < timeout:
        j = http.get(f"/jobs/{job}").json()
        if j["state"] in states:
            return j
        time.sleep(0.1)
    raise AssertionError(f"job {job} not in {states} after {timeout} s: {j}")
