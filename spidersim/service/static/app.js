// spidersim web page: vanilla JS, no external code. The token stays in this tab's
// sessionStorage and goes in the Authorization header of every request; images and
// downloads are fetched with it and shown from blob URLs.
"use strict";
const $ = (id) => document.getElementById(id);
let TOKEN = sessionStorage.getItem("spidersim-token") || "";
let MODEL = null, JOB = null, POLL = null, ARM = null;

async function api(path, opts = {}) {
  opts.headers = Object.assign({"Authorization": "Bearer " + TOKEN}, opts.headers || {});
  const r = await fetch(path, opts);
  if (!r.ok) {
    let msg = r.status + " " + r.statusText;
    try {
      const j = await r.json();
      msg = typeof j.detail === "string" ? j.detail :
        j.detail.map((e) => (e.loc || []).join(".") + ": " + e.msg).join("\n");
    } catch (e) { /* keep the status text */ }
    const err = new Error(msg); err.status = r.status; throw err;
  }
  return r;
}
const json = async (p, o) => (await api(p, o)).json();
const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "text") e.textContent = v; else e.setAttribute(k, v);
  }
  kids.forEach((k) => e.append(k));
  return e;
};
const fmt = (v) => typeof v === "string" ? v : JSON.stringify(v);

// ---------------------------------------------------------------- login
async function login() {
  TOKEN = $("token").value.trim() || TOKEN;
  try {
    const models = await json("/models");
    sessionStorage.setItem("spidersim-token", TOKEN);
    $("login-box").hidden = true; $("app").hidden = false;
    $("who").textContent = "logged in";
    const ul = $("models"); ul.innerHTML = "";
    for (const m of models) {
      const li = el("li", {"data-name": m.name, title: m.description || "", text: m.name});
      li.onclick = () => openModel(m.name);
      ul.append(li);
    }
    refreshJobs();
  } catch (e) {
    $("login-error").textContent = e.status === 401 ? "Token rejected: " + e.message : e.message;
  }
}
$("login").onclick = login;
$("token").addEventListener("keydown", (e) => { if (e.key === "Enter") login(); });

let LISTED = 0;           // the latest job-list request: an earlier one answering late is dropped
async function refreshJobs() {
  const seq = ++LISTED;
  const jobs = await json("/jobs?limit=15");
  if (seq !== LISTED) return;
  const ul = $("jobs"); ul.innerHTML = "";
  for (const j of jobs) {
    const when = new Date(j.created * 1000).toLocaleTimeString();
    const li = el("li", {class: "job-" + (j.expired ? "expired" : j.state), "data-id": j.id,
      text: `${j.model} ${j.state} ${when}` + (j.expired ? " (files removed)" :
                                                 j.bytes ? ` (${size(j.bytes)})` : "")});
    li.onclick = async () => { if (!MODEL || MODEL.name !== j.model) await openModel(j.model);
                               watch(j.id); };
    if (!j.expired && !["queued", "running"].includes(j.state)) {
      const b = el("button", {class: "del", title: "delete this job's result files",
                              text: "Delete"});
      b.onclick = (e) => { e.stopPropagation(); deleteJob(j, `${j.model} ${j.state} ${when}`); };
      li.prepend(b);
    }
    ul.append(li);
  }
  refreshUsage();
}

// bytes as kB, MB or GB (powers of 1000, the unit of the service's limits): "12.3 MB"
function size(n) {
  const [d, u] = n >= 1e9 ? [1e9, "GB"] : n >= 1e6 ? [1e6, "MB"] : [1e3, "kB"];
  const v = n / d;
  return (v >= 100 ? Math.round(v) : +v.toPrecision(3)) + " " + u;
}

// the disk quota (GET /usage): use, reservations of active jobs, and whether a run fits
let USAGE = 0;
async function refreshUsage() {
  const seq = ++USAGE;
  let u;
  try { u = await json("/usage"); } catch (e) { $("usage").textContent = e.message; return; }
  if (seq !== USAGE) return;
  const n = u.active_jobs;
  $("usage").textContent = `Disk: used ${size(u.used_bytes)} of ${size(u.quota_bytes)}` +
    (n ? ` (${n} queued or running job${n > 1 ? "s" : ""} reserve${n > 1 ? "" : "s"} ` +
         `${size(u.reserved_bytes)})` : "");
  const room = u.quota_bytes - u.reserve_per_job_bytes;     // above it a run does not fit
  $("usage").append(el("meter", {min: 0, max: u.quota_bytes, value: u.used_bytes,
                                 low: room, high: room, optimum: 0}));
  const full = u.free_bytes < u.reserve_per_job_bytes;
  $("usage-full").hidden = !full;
  $("usage-full").textContent = full ? `Quota full: a new run needs ` +
    `${size(u.reserve_per_job_bytes)} free, ${size(u.free_bytes)} left. Delete jobs you ` +
    `no longer need` + (n ? ", or wait for the active ones to finish" : "") +
    `; results are removed ${u.keep_days} day(s) after their job ends.` : "";
}

async function deleteJob(j, label) {
  $("jobs-error").textContent = "";
  if (!confirm(`Delete the results of job ${label}?\nIts files are removed for good; ` +
               `it stays listed.`)) return;
  try {
    await json("/jobs/" + j.id, {method: "DELETE"});
    if (JOB === j.id) { $("results").hidden = true; $("message").textContent = "results deleted"; }
  } catch (e) {
    $("jobs-error").textContent = `Could not delete job ${label}: ${e.message}`;
  }
  try { await refreshJobs(); } catch (e) {       // a refusal already shown is not repeated
    if (!$("jobs-error").textContent) $("jobs-error").textContent = e.message; }
}

// ---------------------------------------------------------------- model page
async function openModel(name) {
  MODEL = await json("/models/" + encodeURIComponent(name));
  document.querySelectorAll("#models li").forEach(
    (li) => li.classList.toggle("sel", li.dataset.name === name));
  $("model").hidden = false; $("results").hidden = true;
  $("m-title").textContent = `${MODEL.name} (${MODEL.file})`;
  $("m-desc").textContent = MODEL.description;
  $("m-facts").textContent = `${MODEL.n_blocks} blocks, ${MODEL.n_states} states; ` +
    `default t_end ${MODEL.simulation.t_end} s, ${MODEL.simulation.method}` +
    (MODEL.arm ? `; arm: ${MODEL.arm.n} joints (${MODEL.arm.convention})` : "");
  $("t_end").value = MODEL.simulation.t_end;
  $("signals").textContent = MODEL.signals.map((s) =>
    `${s.name} [${s.unit}]${s.size > 1 ? " x" + s.size : ""}`).join(", ");
  $("message").textContent = ""; $("state").textContent = "idle"; $("progress").value = 0;
  // parameters: the diagram's own, then per block
  const box = $("params"); box.innerHTML = "";
  if (MODEL.parameters.length) {
    const t = el("table", {class: "p"});
    for (const p of MODEL.parameters) t.append(paramRow(p.name, p.value, "", "", ""));
    box.append(el("details", {open: ""}, el("summary", {text: "diagram parameters"}), t));
  }
  for (const b of MODEL.blocks) {
    const t = el("table", {class: "p"});
    for (const p of b.parameters) {
      if (p.kind === "str") continue;
      const bounds = Object.entries(p.bounds).map(([k, v]) =>
        ({gt: ">", ge: ">=", lt: "<", le: "<="})[k] + " " + v).join(", ");
      t.append(paramRow(`${b.path}.${p.name}`, p.value, p.unit, bounds, p.doc, p.name));
    }
    box.append(el("details", {}, el("summary", {text: `${b.path}: ${b.type}`, title: b.doc}), t));
  }
  const ini = $("initial"); ini.innerHTML = "";
  const ti = el("table", {class: "p"});
  for (const [name, s] of Object.entries(MODEL.initial))
    ti.append(paramRow(name, s.value, s.unit, "", s.doc, name, "initial"));
  ini.append(ti);
  commandForm();
}

function paramRow(path, value, unit, bounds, doc, label, group = "parameters") {
  const inp = el("input", {"data-path": path, "data-group": group, "data-orig": fmt(value),
                          value: fmt(value), title: doc || ""});
  return el("tr", {}, el("td", {text: label || path, title: doc || ""}), el("td", {}, inp),
            el("td", {class: "unit", text: (unit && unit !== "1" ? unit : "") +
                                             (bounds ? "  " + bounds : "")}));
}

const parseValue = (text) => { try { return JSON.parse(text); } catch (e) { return text; } };

function changed(group) {
  const out = {};
  document.querySelectorAll(`input[data-group=${group}]`).forEach((i) => {
    if (i.value.trim() !== i.dataset.orig) out[i.dataset.path] = parseValue(i.value.trim());
  });
  return out;
}

// ---------------------------------------------------------------- commands
function commandForm() {
  const c = MODEL.commands, sel = $("cmd-kind");
  sel.innerHTML = "";
  sel.append(el("option", {value: "", text: "model's own references"}));
  if (c.table.length) sel.append(el("option", {value: "table", text: "time table (set points)"}));
  if (c.joint_path.length) sel.append(el("option", {value: "joint_path", text: "joint-space path"}));
  if (c.cartesian_line.length)
    sel.append(el("option", {value: "cartesian_line", text: "Cartesian straight line"}));
  for (const n of Object.keys(c.named))
    sel.append(el("option", {value: "named:" + n, text: "command: " + n}));
  sel.onchange = drawCommand; drawCommand();
}

function field(id, label, value, title = "") {
  return el("label", {title}, label + " ", el("input", {id, value: fmt(value)}));
}

function drawCommand() {
  const k = $("cmd-kind").value, f = $("cmd-form"), c = MODEL.commands;
  f.innerHTML = "";
  if (k === "table") {
    const s = el("select", {id: "c-block"});
    c.table.forEach((t) => s.append(el("option", {value: t.block,
      text: `${t.block} (${t.type}) -> ` + t.feeds.map((x) => `${x.to} [${x.unit}]`).join(", ")})));
    f.append(el("label", {}, "source block ", s), field("c-time", "times [s]", [0, 0.1, 0.3]),
             field("c-value", "values", [0, 1, 1]));
  } else if (k === "joint_path") {
    const s = el("select", {id: "c-block"});
    c.joint_path.forEach((t) => s.append(el("option", {value: t.block, text: `${t.block} (${t.type})`})));
    const p = c.joint_path[0];
    f.append(el("label", {}, "trajectory block ", s), field("c-points", "via points", [p.q0, p.q1]),
             field("c-times", "times [s]", [0.1, 1.0]));
  } else if (k === "cartesian_line") {
    const p = c.cartesian_line[0];
    f.append(field("c-direction", "direction (base frame)", p.direction),
             field("c-distance", "distance [m]", p.distance), field("c-speed", "speed [m/s]", p.speed),
             field("c-accel", "acceleration [m/s2]", p.accel), field("c-t_start", "start [s]", p.t_start));
  } else if (k.startsWith("named:")) {
    const n = k.slice(6), cmd = c.named[n];
    f.append(el("p", {class: "hint", text: cmd.doc}));
    for (const [a, spec] of Object.entries(cmd.arguments))
      f.append(el("label", {title: spec.doc}, `${a} [${spec.unit}] `,
                  el("input", {"data-arg": a, placeholder: spec.doc})));
  }
}

function command() {
  const k = $("cmd-kind").value, v = (id) => parseValue($(id).value);
  if (!k) return null;
  if (k === "table") return {kind: k, block: $("c-block").value, time: v("c-time"), value: v("c-value")};
  if (k === "joint_path") return {kind: k, block: $("c-block").value, points: v("c-points"), times: v("c-times")};
  if (k === "cartesian_line") return {kind: k, direction: v("c-direction"), distance: v("c-distance"),
                                      speed: v("c-speed"), accel: v("c-accel"), t_start: v("c-t_start")};
  const args = {};
  document.querySelectorAll("#cmd-form input[data-arg]").forEach((i) => {
    if (i.value.trim()) args[i.dataset.arg] = parseValue(i.value.trim()); });
  return {kind: "named", name: k.slice(6), arguments: args};
}

// ---------------------------------------------------------------- run, progress, results
$("run").onclick = async () => {
  $("message").textContent = "";
  const body = {model: MODEL.name, parameters: changed("parameters"), initial: changed("initial")};
  const t = parseFloat($("t_end").value); if (!isNaN(t)) body.t_end = t;
  const cmd = command(); if (cmd) body.command = cmd;
  try {
    const job = await json("/jobs", {method: "POST", body: JSON.stringify(body),
                                     headers: {"Content-Type": "application/json"}});
    watch(job.id); refreshJobs();
  } catch (e) { $("message").textContent = e.message; }
};
$("cancel").onclick = async () => { if (JOB) await json(`/jobs/${JOB}/cancel`, {method: "POST"}); };

function watch(id) {
  JOB = id; clearInterval(POLL); $("results").hidden = true;
  $("cancel").disabled = false;
  const tick = async () => {
    const j = await json("/jobs/" + id);
    $("progress").value = j.fraction;
    $("state").textContent = `${j.state}: t = ${j.progress.toPrecision(4)} / ${j.t_end} s`;
    $("message").textContent = j.message || "";
    if (!["queued", "running"].includes(j.state)) {
      clearInterval(POLL); $("cancel").disabled = true; refreshJobs();
      if (j.files) showResults(j);
    }
  };
  POLL = setInterval(tick, 300); tick();
}

async function blobURL(path) { return URL.createObjectURL(await (await api(path)).blob()); }

async function showResults(j) {
  $("results").hidden = false;
  const dl = $("downloads"); dl.innerHTML = "";
  const ext = {"result.npz": "npz", "result.csv": "csv", "report.txt": "txt", "meta.json": "json"};
  for (const n of j.files.data) {
    const a = el("a", {href: "#", text: n}); a.style.marginRight = "1em";
    a.onclick = async (e) => { e.preventDefault();
      const u = await blobURL(`/jobs/${j.id}/result.${ext[n]}`);
      const t = el("a", {href: u, download: `${j.model}_${n}`}); t.click(); };
    dl.append(a);
  }
  const box = $("plots"); box.innerHTML = "";
  for (const p of j.files.plots) {
    const img = el("img", {class: "plot", alt: p, title: p});
    box.append(img);
    img.src = await blobURL(`/jobs/${j.id}/plots/${p}`);
  }
  $("arm-box").hidden = true;
  if (MODEL && MODEL.arm && MODEL.signals.some((s) => s.name === MODEL.arm.signal)) {
    const s = await json(`/jobs/${j.id}/signals/${MODEL.arm.signal}.json?points=200`);
    armView(s);
  }
}

// ---------------------------------------------------------------- 3-D arm view (DH chain)
function fk(q) {          // joint origins in the base frame, standard DH
  let T = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]];
  const pts = [[0, 0, 0]];
  MODEL.arm.dh.forEach((l, i) => {
    const ct = Math.cos(q[i]), st = Math.sin(q[i]), ca = Math.cos(l.alpha), sa = Math.sin(l.alpha);
    const A = [[ct, -st * ca, st * sa, l.a * ct], [st, ct * ca, -ct * sa, l.a * st], [0, sa, ca, l.d]];
    const N = [0, 1, 2].map((r) => [0, 1, 2, 3].map((c) =>
      T[r][0] * A[0][c] + T[r][1] * A[1][c] + T[r][2] * A[2][c] + (c === 3 ? T[r][3] : 0)));
    T = N; pts.push([T[0][3], T[1][3], T[2][3]]);
  });
  return pts;
}

function armView(sig) {
  ARM = sig; $("arm-box").hidden = false;
  const r = $("arm-time"); r.max = sig.t.length - 1; r.value = 0;
  r.oninput = () => drawArm(+r.value);
  $("arm-play").onclick = () => {
    let k = 0; const id = setInterval(() => { r.value = k; drawArm(k); k += 1;
      if (k >= sig.t.length) clearInterval(id); }, 40); };
  drawArm(0);
}

function drawArm(k) {
  const c = $("arm"), g = c.getContext("2d"), q = ARM.values[k];
  const pts = fk(Array.isArray(q) ? q : [q]);
  const az = 0.7, el_ = 0.35, s = 180;               // view angles, pixels per metre
  const P = (p) => { const x = Math.cos(az) * p[0] - Math.sin(az) * p[1];
    const y = Math.sin(az) * p[0] + Math.cos(az) * p[1];
    return [c.width / 2 + s * x, c.height - 110 - s * (p[2] * Math.cos(el_) - y * Math.sin(el_))]; };
  g.clearRect(0, 0, c.width, c.height);
  g.strokeStyle = "#bbb"; g.beginPath();
  [[[-0.5, 0, 0], [0.5, 0, 0]], [[0, -0.5, 0], [0, 0.5, 0]]].forEach(([a, b]) => {
    const A = P(a), B = P(b); g.moveTo(...A); g.lineTo(...B); });
  g.stroke();
  g.strokeStyle = "#1d3557"; g.lineWidth = 6; g.lineCap = "round"; g.beginPath();
  pts.forEach((p, i) => { const [x, y] = P(p); i ? g.lineTo(x, y) : g.moveTo(x, y); });
  g.stroke();
  g.fillStyle = "#e63946"; pts.forEach((p) => { const [x, y] = P(p);
    g.beginPath(); g.arc(x, y, 4, 0, 2 * Math.PI); g.fill(); });
  $("arm-t").textContent = `t = ${ARM.t[k].toFixed(3)} s`;
}

if (TOKEN) { $("token").value = TOKEN; login(); }
