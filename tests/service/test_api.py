"""The real service over HTTP: authorization, limits, validation, runs, results, cancel,
a killed worker, commands. Results are compared with local runs of the same diagram."""
from __future__ import annotations

import io
import json
import os
import signal
import time

import httpx
import numpy as np
import pytest

import spidersim
from spidersim.remote import Client, RemoteError

from .conftest import SERVO, cli, wait_state

SHORT = 0.05


def submit(http, body, status=202):
    r = http.post("/jobs", json=body)
    assert r.status_code == status, r.text
    return r.json()


def test_health_needs_no_token_everything_else_does(server):
    assert httpx.get(server.url + "/health").json()["status"] == "ok"
    api = httpx.get(server.url + "/openapi.json").json()       # the description behind /docs
    assert {"/jobs", "/models/{name}", "/jobs/{job_id}/events"} <= set(api["paths"])
    assert httpx.get(server.url + "/docs").status_code == 200
    anon = server.client(None)
    for path in ("/models", "/models/servo", "/jobs", "/jobs/" + "0" * 32):
        r = anon.get(path)
        assert r.status_code == 401, path
        assert "Bearer" in r.json()["detail"]
    assert anon.post("/jobs", json={"model": "servo"}).status_code == 401
    bad = server.client(server.alice[:-3] + "xyz")
    assert bad.get("/models").status_code == 401
    assert server.client("sst_nope_nope").get("/jobs").status_code == 401


def test_model_library_and_description(server):
    http = server.client(server.alice)
    names = [m["name"] for m in http.get("/models").json()]
    assert names == ["servo", "slow", "trajectory"]
    info = http.get("/models/servo").json()
    motor = next(b for b in info["blocks"] if b["path"] == "motor")
    R = next(p for p in motor["parameters"] if p["name"] == "R")
    assert R["value"] == 1.0 and R["unit"] == "Ohm" or R["unit"]      # unit from the block
    assert R["bounds"] == {"gt": 0.0}
    assert [s["name"] for s in info["signals"]] == ["ref.y", "motor.phi", "motor.w", "motor.i",
                                                    "sat.y"]
    assert info["commands"]["table"][0]["block"] == "ref"
    assert "position_step" in info["commands"]["named"]
    assert info["arm"] is None
    assert http.get("/models/nosuch").status_code == 404


@pytest.mark.parametrize("name", ["..", "../servo", "a..b", "servo.yaml", "/etc/passwd"])
def test_model_name_with_dots_or_slash_is_422(server, name):
    http = server.client(server.alice)
    r = http.post("/jobs", json={"model": name})
    assert r.status_code == 422, r.text
    assert "identifier" in r.json()["detail"]
    # in a URL path, percent-encoded so that no client normalises '..' away
    enc = name.replace(".", "%2E").replace("/", "%2F")
    r = http.get(f"/models/{enc}")
    assert r.status_code in ((422,) if "/" not in name else (404, 422)), r.text


def test_oversized_body_is_413(server):
    http = server.client(server.alice)
    big = {"model": "servo", "command": {"kind": "table", "block": "ref",
                                         "time": list(range(5000)), "value": [0.0] * 5000}}
    r = http.post("/jobs", json=big)
    assert r.status_code == 413
    assert "20000 bytes" in r.json()["detail"]


@pytest.mark.parametrize("body,needle", [
    ({"parameters": {"motor.RR": 1}}, "did you mean R?"),
    ({"parameters": {"motor.R": -1}}, "parameter 'R' must be > 0, got -1"),
    ({"parameters": {"V_mx": 3}}, "no parameter 'V_mx'"),
    ({"t_end": 5000}, "limit of 1000 s"),
    ({"t_end": -1}, "t_end must be a positive"),
    ({"log": ["ref.y", "motor.w", "motor.i", "sat.y", "e_pos.y", "e_spd.y"]},
     "more than the limit of 5"),
    ({"log": ["motor.ww"]}, "no signal 'motor.ww'"),
    ({"initial": {"motor.x": 1}}, "no state 'motor.x'"),
    ({"command": {"kind": "table", "block": "motor", "time": [0], "value": [1]}},
     "'motor' is not a table-commandable source block"),
    ({"command": {"kind": "table", "time": [0, 1, 1], "value": [0, 1, 2]}},
     "'time' must be strictly increasing"),
    ({"command": {"kind": "table", "time": [0, 1], "value": [0]}}, "give one value per time"),
    ({"command": {"kind": "named", "name": "nosuch"}}, "declares no command 'nosuch'"),
    ({"command": {"kind": "cartesian_line", "direction": [1, 0, 0]}},
     "no straight-line path"),
    ({"command": {"kind": "warp"}}, "command"),
    # hostile values: the loader's safe evaluator and parameter checks answer, nothing runs
    ({"parameters": {"motor.R": "__import__('os').system('touch /tmp/spidersim-pwn')"}},
     "is not allowed in a parameter expression"),
    ({"parameters": {"motor.R": "motor.R.__class__"}}, "is not allowed"),
    ({"parameters": {"e_pos.signs": "+-);import os#"}}, "string of '+-' characters"),
    ({"colour": "red"}, "colour"),
    # lone surrogates (JSON escapes \ud800-\udfff) anywhere in the body: no character
    ({"parameters": {"motor.R": "\ud800"}}, "lone surrogate"),
    ({"parameters": {"\udc00": 1}}, "lone surrogate"),
    ({"log": ["\ud800"]}, "lone surrogate"),
    ({"command": {"kind": "named", "name": "\ud800"}}, "lone surrogate"),
    # values with units: checked against the declared or inferred unit
    ({"parameters": {"motor.R": {"value": 1, "unit": "V"}}}, "does not convert"),
    ({"parameters": {"motor.R": {"value": 1, "unit": "parsecs_x"}}}, "unknown unit"),
    # a number in a unit (pint read '1e-3 V' as V/e**3: V_max ran at 5 V), a level
    ({"parameters": {"V_max": {"value": 20, "unit": "1e-3 V"}}}, "a number may only be"),
    ({"parameters": {"V_max": {"value": 20, "unit": "dB"}}}, "logarithmic unit"),
    ({"initial": {"motor.w": {"value": 1, "unit": "m"}}}, "does not convert"),
    ({"command": {"kind": "table", "time": [0, 1], "value": [0, 1], "unit": "A"}},
     "does not convert"),
    ({"command": {"kind": "named", "name": "position_step",
                  "arguments": {"ref.after": {"value": 1, "unit": "N"}}}}, "does not convert"),
])
def test_validation_errors_are_422_with_the_cli_message(server, body, needle):
    http = server.client(server.alice)
    # JSON text with \uXXXX escapes (httpx would refuse to encode a lone surrogate)
    r = http.post("/jobs", content=json.dumps(dict(model="servo", **body)),
                  headers={"Content-Type": "application/json"})
    assert r.status_code == 422, r.text
    assert needle in json.dumps(r.json()["detail"]), r.json()


def test_cli_message_matches(server, tmp_path):
    """The service's message for a bad parameter is the CLI's (file relative to the models)."""
    p = cli("check", SERVO, "--set", "motor.R=-1", check=False)
    assert p.returncode == 2
    cli_msg = p.stderr.split("servo.yaml:", 1)[1].strip()
    r = server.client(server.alice).post("/jobs", json={"model": "servo",
                                                        "parameters": {"motor.R": -1}})
    assert r.json()["detail"].split("servo.yaml:", 1)[1].strip() == cli_msg


def test_run_results_equal_local_run(server, tmp_path):
    c = Client(server.url, server.alice)
    job = c.submit("servo", parameters={"motor.R": 1.3}, t_end=0.3)
    st = c.wait(job, timeout=120)
    assert st["state"] == "done", st
    assert st["progress"] == pytest.approx(0.3)
    r = c.result(job)
    ref = spidersim.load(SERVO, set={"motor.R": 1.3}).simulate(t_end=0.3)
    assert isinstance(r, spidersim.Result)
    assert r.names == ref.names and np.array_equal(r.t, ref.t)
    for n in ref.names:
        assert np.array_equal(r[n], ref[n]), n
    assert r.units == ref.units and r.status == "ok"
    assert r.stats["steps"] == ref.stats["steps"]
    # downloads: csv, per-signal JSON, plots
    http = server.client(server.alice)
    csv = http.get(f"/jobs/{job}/result.csv").text.splitlines()
    assert csv[0].split(",") == ["t [s]"] + [f"{n} [{ref.units[n]}]" for n in ref.names]
    assert len(csv) == len(ref.t) + 1
    sig = http.get(f"/jobs/{job}/signals/motor.w.json", params={"stride": 3}).json()
    assert sig["unit"] == ref.units["motor.w"]
    assert np.array_equal(sig["values"], ref["motor.w"][::3])
    assert http.get(f"/jobs/{job}/signals/nosuch.json").status_code == 404
    assert len(st["files"]["plots"]) == 3
    for p in st["files"]["plots"]:
        assert http.get(f"/jobs/{job}/plots/{p}").content[:4] == b"\x89PNG"
    assert http.get(f"/jobs/{job}/plots/..%2Fmeta.json").status_code == 404
    files = c.download(job, str(tmp_path))
    assert {os.path.basename(f) for f in files} >= {"result.npz", "result.csv", "report.txt"}


def test_other_users_job_is_404(server):
    a, b = server.client(server.alice), server.client(server.bob)
    job = submit(a, {"model": "servo", "t_end": SHORT})["id"]
    for path in (f"/jobs/{job}", f"/jobs/{job}/result.npz", f"/jobs/{job}/events",
                 f"/jobs/{job}/signals/motor.w.json"):
        assert b.get(path).status_code == 404, path
    assert b.post(f"/jobs/{job}/cancel").status_code == 404
    assert job not in [j["id"] for j in b.get("/jobs").json()]
    assert job in [j["id"] for j in a.get("/jobs").json()]
    assert wait_state(a, job)["state"] == "done"


def test_events_stream_progress_until_done(server):
    http = server.client(server.alice)
    job = submit(http, {"model": "slow", "t_end": 20})["id"]
    states, progress = [], []
    with http.stream("GET", f"/jobs/{job}/events", timeout=120) as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            if line.startswith("data: "):
                d = json.loads(line[6:])
                states.append(d["state"])
                progress.append(d["progress"])
    assert states[-1] == "done"
    assert progress == sorted(progress) and progress[-1] == pytest.approx(20)
    assert any(0 < p < 20 for p in progress), progress       # seen part-way


def test_too_many_active_jobs_is_429_and_cancel(server):
    http = server.client(server.bob)
    jobs = [submit(http, {"model": "slow", "t_end": 900})["id"] for _ in range(3)]
    r = http.post("/jobs", json={"model": "servo", "t_end": SHORT})
    assert r.status_code == 429
    assert "limit is 3" in r.json()["detail"] and r.headers["retry-after"]
    t0 = time.time()
    while http.get(f"/jobs/{jobs[0]}").json()["progress"] <= 0:    # running, part-way
        assert time.time() - t0 < 60
        time.sleep(0.1)
    for j in jobs:
        http.post(f"/jobs/{j}/cancel")
    finals = [wait_state(http, j) for j in jobs]
    assert [f["state"] for f in finals] == ["cancelled"] * 3
    assert 0 < finals[0]["progress"] < 900
    # the running one stopped cooperatively and kept its data (tests/service/test_cancel.py);
    # the queued one has none
    assert http.get(f"/jobs/{jobs[0]}/result.npz").status_code == 200
    assert finals[2]["message"] == "cancelled before it started"
    assert http.get(f"/jobs/{jobs[2]}/result.npz").status_code == 409
    # the slots are free again
    job = submit(http, {"model": "servo", "t_end": SHORT})["id"]
    assert wait_state(http, job)["state"] == "done"


def test_killed_worker_fails_its_job_server_keeps_serving(server):
    http = server.client(server.alice)
    job = submit(http, {"model": "slow", "t_end": 900})["id"]
    t0 = time.time()
    while http.get(f"/jobs/{job}").json()["progress"] <= 0:
        assert time.time() - t0 < 60
        time.sleep(0.1)
    victims = server.workers()       # the busy one among them runs the job
    assert victims
    for pid in victims:
        os.kill(pid, signal.SIGKILL)
    st = wait_state(http, job)
    assert st["state"] == "failed"
    assert "killed by SIGKILL" in st["message"]
    job2 = submit(http, {"model": "servo", "t_end": SHORT})["id"]
    assert wait_state(http, job2)["state"] == "done"


def test_commands_table_named_and_initial(server):
    c = Client(server.url, server.alice)
    tt, vv = [0.0, 0.05, 0.1, 0.2], [0.0, 0.5, 0.5, -0.2]
    job = c.submit("servo", t_end=1.0, command={"kind": "table", "block": "ref", "time": tt,
                                                "value": vv})
    assert c.wait(job, 120)["state"] == "done"
    r = c.result(job)
    # the set point is the table, interpolated linearly, end value held
    assert np.allclose(r["ref.y"], np.interp(r.t, tt, vv), atol=1e-12)
    assert r["motor.phi"][-1] == pytest.approx(-0.2, abs=0.02)        # the servo follows
    job = c.submit("servo", t_end=0.3, initial={"motor.w": 5.0},
                   command={"kind": "named", "name": "position_step",
                            "arguments": {"ref.after": 0.25, "ref.t_step": 0.1}})
    assert c.wait(job, 120)["state"] == "done"
    r = c.result(job)
    assert r["motor.w"][0] == 5.0
    assert np.all(r["ref.y"][r.t < 0.1] == 0) and np.all(r["ref.y"][r.t > 0.1] == 0.25)
    with pytest.raises(RemoteError) as e:
        c.submit("servo", command={"kind": "named", "name": "position_step",
                                   "arguments": {"ref.after": 1}}, parameters={"ref.after": 2})
    assert e.value.status == 422 and "set by the command" in str(e.value)


def test_joint_path_of_four_via_points_runs_on_the_server(server):
    """More than 2 via points: the server replaces the QuinticProfile by a ViaPointProfile;
    the recorded reference passes through every point at its time (event times are
    samples) and equals a local run of the same path."""
    c = Client(server.url, server.alice)
    assert c.model("trajectory")["commands"]["joint_path"][0]["block"] == "ref"
    q, tv = [0.0, 0.5, 1.2, -0.3], [0.1, 0.6, 1.1, 1.7]
    job = c.submit("trajectory", t_end=2.0,
                   command={"kind": "joint_path", "block": "ref", "points": q, "times": tv})
    assert c.wait(job, 120)["state"] == "done"
    r = c.result(job)
    assert [e[0] for e in r.events] == tv
    # velocities by the rule: slopes 1.0, 1.4 at point 1 (mean), 1.4, -2.5 at point 2 (0)
    for qk, tk, vk in zip(q, tv, [0.0, 1.2, 0.0, 0.0]):
        k = np.flatnonzero(r.t == tk)
        assert k.size >= 1, f"via time {tk} is not a sample"
        assert r["ref.q"][k] == pytest.approx(qk, abs=1e-12)
        assert r["ref.qd"][k[-1]] == pytest.approx(vk, abs=1e-12)
    assert np.all(r["ref.q"][r.t > tv[-1]] == q[-1])
    local = spidersim.loads(
        "blocks:\n  ref: {type: ViaPointProfile, points: %s, times: %s}\n"
        "  acc: {type: Integrator}\nconnections: [ref.q -> acc.u]\n" % (q, tv)).simulate(
        t_end=2.0)
    assert np.array_equal(r.t, local.t)
    for s in ("ref.q", "ref.qd", "acc.y"):
        np.testing.assert_allclose(r[s], local[s], rtol=0, atol=1e-12)
    with pytest.raises(RemoteError) as e:
        c.submit("trajectory", parameters={"ref.T": 2}, command={
            "kind": "joint_path", "points": q, "times": tv})
    assert e.value.status == 422 and "replaces by a ViaPointProfile" in str(e.value)


def test_idempotency_key_returns_the_first_job(server):
    http = server.client(server.alice)
    body = {"model": "servo", "t_end": SHORT}
    r1 = http.post("/jobs", json=body, headers={"Idempotency-Key": "k-1"})
    r2 = http.post("/jobs", json=body, headers={"Idempotency-Key": "k-1"})
    assert r1.status_code == 202 and r2.status_code == 200
    assert r1.json()["id"] == r2.json()["id"]
    # the same key for another request is the client's bug, not a retry: refused, and the
    # first job is not handed back as if it were the new one's
    r3 = http.post("/jobs", json=dict(body, t_end=2 * SHORT), headers={"Idempotency-Key": "k-1"})
    assert r3.status_code == 422 and "different request" in r3.json()["detail"], r3.text
    wait_state(http, r1.json()["id"])


def test_cli_run_remote(server, tmp_path):
    out = tmp_path / "res"
    p = cli("run", "servo", "--remote", server.url, "--token", server.alice, "--t-end", "0.2",
            "--set", "motor.R=1.1", "--out", str(out))
    assert "done" in p.stdout
    z = np.load(out / "result.npz")
    ref = spidersim.load(SERVO, set={"motor.R": 1.1}).simulate(t_end=0.2)
    assert np.array_equal(z["motor.i"], ref["motor.i"])
    assert (out / "position.png").exists()
    p = cli("run", "servo", "--remote", server.url, "--token", "sst_x_y", check=False)
    assert p.returncode == 2 and "HTTP 401" in p.stderr and "Traceback" not in p.stderr
