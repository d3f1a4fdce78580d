"""Benchmark of the remote simulation service with the servo model.

1. Overhead: one remote run (submit, poll until done, fetch the Result) against the same run
   done locally (load + simulate in this process, compiled code warm), interleaved, median
   of ``--repeat`` pairs.
2. Throughput: ``--jobs`` jobs submitted by ``--clients`` concurrent clients; jobs per minute
   of the service beside the same runs done serially in this process.

    python tools/bench_service.py [--workers 2] [--jobs 60] [--clients 10] [--t-end 0.2]

The service is started here (``spidersim serve`` on a free loopback port, a temporary data
folder); numba's cache (SPIDERSIM_CACHE) is shared with the workers.
"""
from __future__ import annotations

import argparse
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import httpx  # noqa: E402

import spidersim  # noqa: E402
from spidersim.remote import Client  # noqa: E402

SERVO = os.path.join(ROOT, "diagrams", "servo.yaml")


def start(data, workers):
    out = subprocess.run([sys.executable, "-m", "spidersim.cli", "serve", "--add-user",
                          "bench", "--data", data], capture_output=True, text=True,
                         check=True).stdout
    token = re.search(r"(sst_\S+)", out).group(1)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "spidersim.cli", "serve", "--port",
                             str(port), "--data", data, "--models", SERVO, "--workers",
                             str(workers), "--max-jobs", "1000"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    for _ in range(300):
        try:
            if httpx.get(url + "/health", timeout=1).status_code == 200:
                return proc, url, token
        except httpx.HTTPError:
            time.sleep(0.1)
    raise SystemExit("the service did not start")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=60)
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--t-end", type=float, default=0.2)
    a = ap.parse_args()
    data = tempfile.mkdtemp(prefix="spidersim-bench-")
    proc, url, token = start(data, a.workers)
    try:
        c = Client(url, token)
        for _ in range(a.workers * 2):                 # warm every worker
            c.wait(c.submit("servo", t_end=a.t_end), 300)
        spidersim.load(SERVO).simulate(t_end=a.t_end)  # warm this process

        local, remote = [], []
        for k in range(a.repeat):
            R = 1.0 + 0.01 * k
            t0 = time.perf_counter()
            spidersim.load(SERVO, set={"motor.R": R}).simulate(t_end=a.t_end)
            local.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            job = c.submit("servo", parameters={"motor.R": R}, t_end=a.t_end, plots=False)
            c.wait(job, 300, poll=0.01)
            c.result(job)
            remote.append(time.perf_counter() - t0)
        ml, mr = statistics.median(local), statistics.median(remote)
        print(f"one servo run (t_end = {a.t_end:g} s), median of {a.repeat}:")
        print(f"  local  {1e3 * ml:8.1f} ms   (load + simulate, warm)")
        print(f"  remote {1e3 * mr:8.1f} ms   (submit + poll + fetch Result, no plots)")
        print(f"  overhead of the service: {1e3 * (mr - ml):.1f} ms per run "
              f"({mr / ml:.1f}x)")

        t0 = time.perf_counter()
        for k in range(a.jobs):
            spidersim.load(SERVO, set={"motor.R": 1.0 + 0.001 * k}).simulate(t_end=a.t_end)
        serial = time.perf_counter() - t0
        ids, lock = [], threading.Lock()

        def client(k):
            cc = Client(url, token)
            for n in range(k, a.jobs, a.clients):
                j = cc.submit("servo", parameters={"motor.R": 1.0 + 0.001 * n},
                              t_end=a.t_end, plots=False)
                with lock:
                    ids.append(j)
        t0 = time.perf_counter()
        th = [threading.Thread(target=client, args=(k,)) for k in range(a.clients)]
        for t in th:
            t.start()
        for t in th:
            t.join()
        states = [c.wait(j, 600, poll=0.05)["state"] for j in ids]
        wall = time.perf_counter() - t0
        assert states.count("done") == a.jobs, states
        print(f"{a.jobs} servo jobs (t_end = {a.t_end:g} s, no plots):")
        print(f"  service, {a.workers} workers, {a.clients} clients: {wall:6.2f} s  "
              f"{60 * a.jobs / wall:8.0f} jobs/min")
        print(f"  local, serial in one process:        {serial:6.2f} s  "
              f"{60 * a.jobs / serial:8.0f} runs/min")
        print(f"  ratio service / local: {serial / wall:.2f}")
        with_plots = []
        for _ in range(5):
            t0 = time.perf_counter()
            c.wait(c.submit("servo", t_end=a.t_end), 300, poll=0.01)
            with_plots.append(time.perf_counter() - t0)
        print(f"  a run with its 3 PNG plots: {1e3 * statistics.median(with_plots):.0f} ms "
              f"(median of 5)")
    finally:
        proc.terminate()
        proc.wait(20)


if __name__ == "__main__":
    main()
