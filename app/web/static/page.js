/* The design page: a client of the public /v1 API (no private endpoints, no libraries, no build step).
 *
 * The form is checked as you type against the same rules the service applies (app/api/validation.py): a malformed
 * matrix is reported at its field and nothing is sent. Whatever the service still rejects comes back as a 422
 * problem+json whose errors[].pointer names the field; each is shown at that field. */
"use strict";

const $ = (id) => document.getElementById(id);
const state = { examples: [], schema: null, job: null, stream: null, modes: 0 };

// ---------------------------------------------------------------- matrices
/** Parse "[1 2; 3 4]" (MATLAB) or "[[1, 2], [3, 4]]" (JSON) into rows; throws Error(message) when malformed. */
function parseMatrix(text) {
  const s = text.trim();
  if (!s) throw new Error("empty: enter a matrix such as [1 2; 3 4]");
  if (/^\[\s*\[/.test(s)) {
    let v;
    try { v = JSON.parse(s); } catch (e) { throw new Error("not valid JSON: " + e.message); }
    if (!Array.isArray(v) || !v.every(Array.isArray)) throw new Error("JSON matrix must be a list of rows");
    v.forEach((row, i) => row.forEach((x, j) => {
      if (typeof x !== "number" || !isFinite(x)) throw new Error(`entry (${i + 1}, ${j + 1}) is not a finite number`);
    }));
    return checkRows(v);
  }
  const body = s.replace(/^\[/, "").replace(/\]$/, "");
  if (/[\[\]]/.test(body)) throw new Error("unbalanced brackets: write [1 2; 3 4]");
  const rows = body.split(/;|\n/).map((r) => r.trim()).filter((r) => r.length > 0);
  if (!rows.length) throw new Error("empty: enter a matrix such as [1 2; 3 4]");
  const out = rows.map((r, i) => r.split(/[\s,]+/).filter((x) => x.length).map((tok, j) => {
    const x = Number(tok);
    if (!/^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(tok) || !isFinite(x)) {
      throw new Error(`entry (${i + 1}, ${j + 1}) "${tok}" is not a number`);
    }
    return x;
  }));
  return checkRows(out);
}

function checkRows(rows) {
  if (!rows.length) throw new Error("matrix has no rows");
  if (!rows[0].length) throw new Error("matrix row is empty");
  rows.forEach((r, i) => {
    if (r.length !== rows[0].length) throw new Error(`row ${i + 1} has ${r.length} entries, row 1 has ${rows[0].length}`);
  });
  return rows;
}

function fmt(x) {
  if (x === null || x === undefined) return "-";
  if (typeof x !== "number") return String(x);
  if (x === 0) return "0";
  const a = Math.abs(x);
  return (a >= 1e4 || a < 1e-3) ? x.toExponential(4) : String(Number(x.toPrecision(6)));
}

function matlab(m) { return "[" + m.map((r) => r.map((x) => String(x)).join(" ")).join("; ") + "]"; }

function numbers(text, what) {
  const s = text.trim();
  if (!s) return null;
  const parts = s.replace(/^\[|\]$/g, "").split(/[\s,;]+/).filter((x) => x.length);
  return parts.map((tok, i) => {
    const x = Number(tok);
    if (!isFinite(x) || !/^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(tok)) {
      throw new Error(`${what}: entry ${i + 1} "${tok}" is not a number`);
    }
    return x;
  });
}

function names(text) {
  const s = text.trim();
  return s ? s.split(",").map((x) => x.trim()).filter((x) => x.length) : null;
}

// ---------------------------------------------------------------- modes of the plant family
function addMode(name, a, b) {
  const i = state.modes++;
  const div = document.createElement("fieldset");
  div.className = "mode";
  div.id = `mode-${i}`;
  div.innerHTML = `<legend>Mode <span class="mode-no"></span></legend>
    <div class="row"><label for="mode-name-${i}">Name (optional)</label>
      <input id="mode-name-${i}" class="mode-name" aria-describedby="err-mode-name-${i}"><p class="err" id="err-mode-name-${i}"></p></div>
    <div class="pair">
      <div class="row"><label for="A-${i}" class="A-label">A</label>
        <textarea id="A-${i}" class="mat-A" rows="3" spellcheck="false" aria-describedby="err-A-${i}"></textarea>
        <p class="err" id="err-A-${i}"></p></div>
      <div class="row"><label for="B-${i}" class="B-label">B</label>
        <textarea id="B-${i}" class="mat-B" rows="3" spellcheck="false" aria-describedby="err-B-${i}"></textarea>
        <p class="err" id="err-B-${i}"></p></div>
    </div>
    <button type="button" class="remove-mode">Remove this mode</button>`;
  $("modes").appendChild(div);
  div.querySelector(".mode-name").value = name || "";
  div.querySelector(".mat-A").value = a || "";
  div.querySelector(".mat-B").value = b || "";
  div.querySelector(".remove-mode").addEventListener("click", () => { div.remove(); relabelModes(); validateSoon(); });
  relabelModes();
  return div;
}

function modeDivs() { return Array.from($("modes").querySelectorAll("fieldset.mode")); }

function relabelModes() {
  const kind = plantKind();
  modeDivs().forEach((d, l) => {
    d.querySelector(".mode-no").textContent = String(l + 1);
    d.querySelector(".A-label").textContent = (kind === "discrete" ? "F" : "A") + ` of mode ${l + 1} (n\u00d7n)`;
    d.querySelector(".B-label").textContent = (kind === "discrete" ? "G" : "B") + ` of mode ${l + 1} (n\u00d7m)`;
    d.querySelector(".remove-mode").hidden = modeDivs().length < 2;
  });
}

function plantKind() { return document.querySelector("input[name=kind]:checked").value; }

function setKind(kind) {
  document.querySelector(`input[name=kind][value=${kind}]`).checked = true;
  $("matrix-plant").hidden = kind === "dc_motor";
  $("motor-plant").hidden = kind !== "dc_motor";
  relabelModes();
}

// ---------------------------------------------------------------- errors at fields
function clearErrors() {
  document.querySelectorAll(".err").forEach((p) => { p.textContent = ""; });
  document.querySelectorAll("[aria-invalid]").forEach((el) => el.removeAttribute("aria-invalid"));
}

function showError(fieldId, message) {
  const field = $(fieldId);
  const box = $("err-" + fieldId) || $("err-form");
  box.textContent = box.textContent ? box.textContent + " " + message : message;
  if (field) field.setAttribute("aria-invalid", "true");
  return field;
}

/** The form field a JSON pointer of the request names (the page builds the request, so it knows its layout). */
function fieldOf(pointer) {
  const p = pointer.split("/").slice(1);
  const mode = (l) => modeDivs()[Number(l)];
  if (p[0] === "plant") {
    if (["A", "B", "F", "G"].includes(p[1])) {
      const d = p[2] !== undefined ? mode(p[2]) : modeDivs()[0];
      if (d) return d.querySelector(p[1] === "A" || p[1] === "F" ? ".mat-A" : ".mat-B").id;
    }
    if (p[1] === "sampling_period") return "h";
    if (p[1] === "mode_names") { const d = mode(p[2] || 0); return d ? d.querySelector(".mode-name").id : null; }
    if ($(p[1])) return p[1];
    return null;
  }
  if (p[0] === "options") {
    if (p[1] === "decay_rate") return "decay";
    return $(p[1]) ? p[1] : null;
  }
  if (p[0] === "weights") return p[1] === "R" ? "R" : "Q";
  if (p[0] === "network") return $("network").hidden ? "network_json" : "network";
  if (p[0] === "channel") return p[1] === "loss" ? "channel_loss" : "channel";
  if ($(p[0])) return p[0];
  return null;
}

function showProblem(problem) {
  const errs = problem.errors || [];
  let first = null;
  if (!errs.length) showError("form", problem.detail || problem.title || "The service refused the request.");
  for (const e of errs) {
    const id = fieldOf(e.pointer || "");
    const el = showError(id || "form", (id ? "" : (e.pointer || "") + ": ") + e.msg);
    first = first || el;
  }
  if (errs.length) {
    $("err-form").replaceChildren(`The service did not accept the request: ${errs.length} field${errs.length > 1 ? "s" : ""} to fix`,
      ...(problem.type ? [" (", el("a", { href: problem.type, text: "how to fix it" }), ")"] : []), ".");
  }
  (first || $("submit")).focus();
}

// ---------------------------------------------------------------- the request from the form
/** The request body, or null after showing every error at its field. */
function buildRequest(live) {
  clearErrors();
  let ok = true;
  // While typing, a field not filled in yet is not an error to shout about; on submit it is.
  const fail = (id, msg) => { ok = false; if (!(live && $(id) && !$(id).value.trim())) showError(id, msg); };
  const num = (id, what, cond, condMsg) => {
    const s = $(id).value.trim();
    const x = Number(s);
    if (!s || !isFinite(x)) { fail(id, `${what} must be a number`); return null; }
    if (cond && !cond(x)) { fail(id, condMsg); return null; }
    return x;
  };
  const kind = plantKind();
  const plant = { kind };
  if (kind === "dc_motor") {
    try {
      const j = numbers($("inertias").value, "inertias");
      if (!j || !j.length) fail("inertias", "give at least one inertia (one per mode)");
      else if (j.some((x) => x <= 0)) fail("inertias", "inertias must be > 0 (kg m^2)");
      else plant.inertias = j;
    } catch (e) { fail("inertias", e.message); }
    for (const [id, positive] of [["resistance", true], ["inductance", true], ["torque_constant", false],
      ["back_emf_constant", false], ["damping", false]]) {
      const x = num(id, id.replace(/_/g, " "), positive ? (v) => v > 0 : (id === "damping" ? (v) => v >= 0 : null),
        positive ? "must be > 0" : "must be >= 0");
      if (x !== null) plant[id] = x;
    }
  } else {
    const [a, b] = kind === "discrete" ? ["F", "G"] : ["A", "B"];
    const As = [], Bs = [], mnames = [];
    let n = null, m = null;
    modeDivs().forEach((d, l) => {
      const ta = d.querySelector(".mat-A"), tb = d.querySelector(".mat-B");
      let A = null, B = null;
      try { A = parseMatrix(ta.value); } catch (e) { fail(ta.id, `${a} of mode ${l + 1}: ${e.message}`); }
      try { B = parseMatrix(tb.value); } catch (e) { fail(tb.id, `${b} of mode ${l + 1}: ${e.message}`); }
      if (A && A.length !== A[0].length) { fail(ta.id, `${a} of mode ${l + 1} must be square, got ${A.length} x ${A[0].length}`); A = null; }
      if (A && n !== null && A.length !== n) { fail(ta.id, `${a} of mode ${l + 1} is ${A.length} x ${A.length} but mode 1 has n = ${n} states: all modes need the same n`); A = null; }
      if (A && n === null) n = A.length;
      if (A && B && B.length !== A.length) { fail(tb.id, `${b} of mode ${l + 1} has ${B.length} rows, ${a} has ${A.length}`); B = null; }
      if (B && m !== null && B[0].length !== m) { fail(tb.id, `${b} of mode ${l + 1} has ${B[0].length} columns but mode 1 has m = ${m} inputs`); B = null; }
      if (B && m === null) m = B[0].length;
      As.push(A); Bs.push(B);
      mnames.push(d.querySelector(".mode-name").value.trim());
    });
    if (!modeDivs().length) fail("form", "add at least one plant mode");
    plant[a] = As; plant[b] = Bs;
    if (mnames.some((x) => x)) {
      if (mnames.some((x) => !x)) modeDivs().forEach((d, l) => { if (!mnames[l]) fail(d.querySelector(".mode-name").id, "name every mode, or none"); });
      else plant.mode_names = mnames;
    }
  }
  const hs = $("h").value.trim();
  if (hs || kind !== "discrete") {
    const h = num("h", "the sampling period", (x) => x > 0, "the sampling period must be > 0 seconds");
    if (h !== null) plant.sampling_period = h;
  }
  const sn = names($("state_names").value), inn = names($("input_names").value);
  if (sn) plant.state_names = sn;
  if (inn) plant.input_names = inn;
  if ($("units").value.trim()) {
    const units = {};
    for (const pair of $("units").value.split(",")) {
      const [k, v] = pair.split("=").map((x) => (x || "").trim());
      if (!k || v === undefined || pair.indexOf("=") < 0) { fail("units", `"${pair.trim()}" is not name=unit`); continue; }
      units[k] = v;
    }
    plant.units = units;
  }
  const req = { plant };
  const label = $("label").value.trim();
  if (label) req.label = label;
  const nd = $("n_drop").value.trim();
  if (!/^\d+$/.test(nd) || Number(nd) < 1) fail("n_drop", "N_drop must be a whole number >= 1");
  else req.n_drop = Number(nd);
  req.method = $("method").value;
  const options = { plant_switching: $("plant_switching").value, scheme: $("scheme").value, solver: $("solver").value };
  const decay = $("decay").value;
  if (decay === "number") {
    const x = num("decay_value", "the decay rate", (v) => v > 0 && v <= 1, "the decay rate must be in (0, 1]");
    if (x !== null) options.decay_rate = x;
    if (x === null) showError("decay", "");
  } else options.decay_rate = decay === "none" ? null : decay;
  if (req.method === "ccl") {
    const it = $("max_iter").value.trim();
    if (!/^\d+$/.test(it) || Number(it) < 1 || Number(it) > 1000) fail("max_iter", "the iteration cap must be a whole number in 1..1000");
    else options.max_iter = Number(it);
  }
  req.options = options;
  if (!$("network-row").hidden) {
    if (!$("network").hidden && $("network").value) {
      const v = $("network").value;
      try { req.network = JSON.parse(v); } catch (e) { req.network = v; }
    } else if (!$("network_json").hidden && $("network_json").value.trim()) {
      try { req.network = JSON.parse($("network_json").value); } catch (e) { fail("network_json", "not valid JSON: " + e.message); }
    }
  }
  if ($("channel").value === "bernoulli") {
    const p = num("channel_loss", "the loss probability", (v) => v >= 0 && v <= 1, "the loss probability must be in [0, 1]");
    if (p !== null) { req.channel = { kind: "bernoulli", loss: p }; req.exhausted = $("exhausted").value; }
  }
  const nStates = kind === "dc_motor" ? 2 : (plant.A || plant.F || [])[0]?.length;
  const nInputs = kind === "dc_motor" ? 1 : ((plant.B || plant.G || [])[0] || [[]])[0]?.length;
  for (const id of ["x0", "u_max"]) {
    try {
      const v = numbers($(id).value, id);
      if (v) {
        const want = id === "x0" ? nStates : nInputs;
        if (want && v.length !== want) fail(id, `${id} has ${v.length} entries, the plant has ${want} ${id === "x0" ? "states" : "inputs"}`);
        else if (id === "u_max" && v.some((x) => x <= 0)) fail(id, "input limits must be > 0");
        else req[id] = v;
      }
    } catch (e) { fail(id, e.message); }
  }
  req.objective = $("objective").value;
  if (req.objective === "cost" && ($("Q").value.trim() || $("R").value.trim())) {
    try {
      const Q = parseMatrix($("Q").value || eye(nStates)), R = parseMatrix($("R").value || eye(nInputs));
      req.weights = { Q, R };
    } catch (e) { fail($("Q").value.trim() ? "Q" : "R", e.message); }
  }
  if (!ok) return null;
  return req;
}

function showChannel() {
  $("channel-loss-row").hidden = $("exhausted-row").hidden = $("channel").value !== "bernoulli";
}

function eye(n) { return matlab(Array.from({ length: n || 1 }, (_, i) => Array.from({ length: n || 1 }, (_, j) => (i === j ? 1 : 0)))); }

let validateTimer = null;
function validateSoon() {
  clearTimeout(validateTimer);
  validateTimer = setTimeout(() => { if (plantKind() === "dc_motor" || modeDivs().some((d) => d.querySelector(".mat-A").value.trim())) buildRequest(true); }, 300);
}

// ---------------------------------------------------------------- the form from a request
function fillForm(req) {
  const p = req.plant || {};
  setKind(p.kind || "continuous");
  $("modes").innerHTML = "";
  state.modes = 0;
  if (p.kind === "dc_motor") {
    $("inertias").value = (p.inertias || []).join(", ");
    for (const id of ["resistance", "inductance", "torque_constant", "back_emf_constant", "damping"]) {
      if (p[id] !== undefined) $(id).value = p[id];
    }
    addMode("", "", "");
  } else {
    const As = p.A || p.F || [], Bs = p.B || p.G || [];
    As.forEach((A, l) => addMode((p.mode_names || [])[l] || "", matlab(A), matlab(Bs[l] || [[]])));
    if (!As.length) addMode("", "", "");
  }
  $("h").value = p.sampling_period !== undefined && p.sampling_period !== null ? p.sampling_period : "";
  $("state_names").value = (p.state_names || []).join(", ");
  $("input_names").value = (p.input_names || []).join(", ");
  $("units").value = Object.entries(p.units || {}).map(([k, v]) => `${k}=${v}`).join(", ");
  $("label").value = req.label || "";
  $("n_drop").value = req.n_drop || 3;
  $("method").value = req.method || "lmi";
  const o = req.options || {};
  const d = o.decay_rate === undefined ? "auto" : o.decay_rate;
  $("decay").value = d === null ? "none" : (typeof d === "number" ? "number" : d);
  if (typeof d === "number") $("decay_value").value = d;
  $("decay_value").disabled = $("decay").value !== "number";
  $("plant_switching").value = o.plant_switching || "per_interval";
  $("scheme").value = o.scheme || "predictive";
  $("solver").value = o.solver || "AUTO";
  $("max_iter").value = o.max_iter || 50;
  $("objective").value = req.objective === "cost" ? "cost" : "stability";
  $("weights").hidden = $("objective").value !== "cost";
  $("Q").value = req.weights ? matlab(req.weights.Q) : "";
  $("R").value = req.weights ? matlab(req.weights.R) : "";
  $("channel").value = req.channel && req.channel.kind === "bernoulli" ? "bernoulli" : "";
  if (req.channel && req.channel.kind === "bernoulli") $("channel_loss").value = req.channel.loss;
  $("exhausted").value = req.exhausted || "hold";
  showChannel();
  $("x0").value = (req.x0 || []).join(", ");
  $("u_max").value = (req.u_max || []).join(", ");
  if (!$("network-row").hidden) {
    const v = req.network === undefined || req.network === null ? "" : (typeof req.network === "string" ? req.network : JSON.stringify(req.network));
    $("network").value = v;
    $("network_json").value = v;
  }
  clearErrors();
}

// ---------------------------------------------------------------- HTTP
function headers(extra) {
  const h = Object.assign({}, extra || {});
  const key = $("api_key").value.trim();
  if (key) h["X-API-Key"] = key;
  return h;
}

async function api(method, path, body, extra) {
  const init = { method, headers: headers(extra) };
  if (body !== undefined) {
    init.body = JSON.stringify(body);
    init.headers["Content-Type"] = "application/json";
  }
  const resp = await fetch(path, init);
  if (resp.status === 401) {
    showError("api_key", "The service needs an API key: enter it here and try again.");
    $("api_key").focus();
  }
  return resp;
}

async function download(path, filename) {
  const resp = await api("GET", path);
  if (!resp.ok) {
    const p = await resp.json().catch(() => ({}));
    showError("form", `${filename}: ${p.detail || resp.statusText}`);
    return;
  }
  saveBlob(await resp.blob(), filename);
}

function saveBlob(blob, filename) {
  const url = URL.createObjectURL(blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

// ---------------------------------------------------------------- running a job
async function submit(ev) {
  ev.preventDefault();
  clearTimeout(validateTimer); // a check still pending from typing would wipe the service's answer
  const req = buildRequest();
  if (!req) {
    $("err-form").textContent = "Fix the fields marked above; nothing was sent.";
    const bad = document.querySelector("[aria-invalid=true]");
    if (bad) bad.focus();
    return;
  }
  $("submit").disabled = true;
  $("progress").textContent = "Submitting\u2026";
  try {
    const resp = await api("POST", "/v1/designs", req);
    const body = await resp.json().catch(() => ({}));
    if (resp.status === 422) { $("progress").textContent = ""; showProblem(body); return; }
    if (!resp.ok) {
      $("progress").textContent = "";
      if (resp.status !== 401) showError("form", `${body.title || resp.status}: ${body.detail || ""}`);
      return;
    }
    openJob(body.id, body);
  } catch (e) {
    showError("form", "The service did not answer: " + e.message);
    $("progress").textContent = "";
  } finally {
    $("submit").disabled = false;
  }
}

function openJob(id, job) {
  if (location.hash !== "#job=" + id) history.pushState(null, "", "#job=" + id);
  state.job = job || { id };
  watch(id);
}

/** Follow a job on its Server-Sent Events stream (read with fetch, so the API key header goes along). */
async function watch(id) {
  if (state.stream) state.stream.abort();
  const ctl = new AbortController();
  state.stream = ctl;
  $("cancel").disabled = false;
  $("result").hidden = true;
  $("progress").textContent = "Waiting for the job\u2026";
  try {
    const resp = await fetch(`/v1/designs/${encodeURIComponent(id)}/events`, { headers: headers(), signal: ctl.signal });
    if (!resp.ok) {
      const p = await resp.json().catch(() => ({}));
      $("progress").textContent = "";
      $("cancel").disabled = true;
      if (resp.status !== 401) showError("form", `Job ${id}: ${p.detail || resp.statusText}`);
      return;
    }
    const reader = resp.body.getReader();
    const dec = new TextDecoder();
    let buf = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buf += dec.decode(value, { stream: true });
      let cut;
      while ((cut = buf.indexOf("\n\n")) >= 0) {
        const chunk = buf.slice(0, cut);
        buf = buf.slice(cut + 2);
        let event = "message", data = "";
        for (const line of chunk.split("\n")) {
          if (line.startsWith("event:")) event = line.slice(6).trim();
          else if (line.startsWith("data:")) data += line.slice(5).trim();
        }
        if (!data) continue;
        const obj = JSON.parse(data);
        if (event === "status") $("progress").textContent = `Job ${obj.status}` + (obj.status === "queued" ? " (waiting for a worker)" : "\u2026");
        else if (event === "progress") $("progress").textContent = progressText(obj);
        else if (event === "end") { finished(obj); return; }
      }
    }
  } catch (e) {
    if (e.name !== "AbortError") showError("form", "The event stream broke: " + e.message);
  } finally {
    if (state.stream === ctl) state.stream = null;
  }
}

function progressText(p) {
  const bits = ["Running"];
  if (p.iteration !== null && p.iteration !== undefined) bits.push(`iteration ${p.iteration}`);
  if (p.step !== null && p.step !== undefined) bits.push(`step ${p.step}${p.total ? " of " + p.total : ""}`);
  if (p.elapsed) bits.push(`${p.elapsed.toFixed(1)} s`);
  if (p.theorem1) bits.push("a certified iterate found");
  return bits.join(", ") + "\u2026";
}

async function cancelJob() {
  if (!state.job) return;
  $("cancel").disabled = true;
  $("progress").textContent = "Cancelling\u2026";
  const resp = await api("POST", `/v1/designs/${encodeURIComponent(state.job.id)}/cancel`);
  if (!resp.ok && resp.status !== 401) {
    const p = await resp.json().catch(() => ({}));
    showError("form", p.detail || resp.statusText);
  }
}

// ---------------------------------------------------------------- the result
function finished(job) {
  state.job = job;
  $("cancel").disabled = true;
  $("progress").textContent = `Job ${job.status}.`;
  if (job.request) fillForm(job.request);
  render(job);
  loadJobs();
}

function el(tag, attrs, ...kids) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "text") e.textContent = v; else if (k === "on") e.addEventListener("click", v); else e.setAttribute(k, v);
  }
  for (const k of kids) e.append(k);
  return e;
}

const CERT_WORDS = {
  common_quadratic: "common quadratic Lyapunov function",
  switched: "mode-dependent (switched) Lyapunov functions",
  farkas: "Farkas certificate: PSD multipliers that rule out every design of this method",
  farkas_limits: "Farkas certificate including the input limits",
  uncontrollable: "an unstable mode no input reaches",
};

function verdictText(job) {
  const r = job.result || {};
  const N = job.n_drop || r.n_drop;
  const cert = r.certificate || {};
  const how = CERT_WORDS[cert.kind] || cert.kind || "";
  if (job.status === "cancelled") return ["Cancelled: the job was stopped before it finished; nothing is certified.", "bad"];
  if (job.status === "failed") return [`The job failed: ${(job.error && (job.error.message || job.error.detail)) || "see the job JSON"}.`, "bad"];
  if (job.status !== "succeeded") return [`The job is ${job.status}.`, ""];
  const losses = N - 1 === 1 ? "1 lost packet" : `${N - 1} lost packets`;
  switch (r.outcome) {
    case "stabilized":
      return [`Stabilized for every pattern of at most ${losses} in a row` +
        (r.plant_switching === "per_sample" ? " and every plant switching" : " and every switching of the plant modes") +
        `, proven (${how}${cert.verified ? ", re-checked" : ", NOT re-checked"}).`, "good"];
    case "infeasible":
      return ["No such controller exists: proof attached" + (how ? ` (${how}${cert.verified ? ", re-checked" : ""})` : "") + ".", "bad"];
    case "marginal":
      return ["Not certified: every design with a margin above the certificate's is excluded, a design with a smaller margin may exist.", "bad"];
    default:
      return [`Not certified (${r.outcome || "no outcome"}): ${r.message || ""}`, "bad"];
  }
}

function render(job) {
  const r = job.result || {};
  const box = $("result");
  box.hidden = false;
  const [text, cls] = verdictText(job);
  $("verdict").textContent = text;
  $("verdict").className = "verdict " + cls;
  const link = location.origin + location.pathname + "#job=" + job.id;
  $("job-link").replaceChildren("Shareable link to this job: ", el("a", { href: "#job=" + job.id, id: "share-link", text: link }));
  for (const id of ["proof", "numbers", "gains", "figures", "downloads"]) $(id).replaceChildren();
  const cert = r.certificate;
  if (cert) {
    const dl = el("dl");
    const add = (k, v) => { if (v !== null && v !== undefined) dl.append(el("dt", { text: k }), el("dd", { text: v })); };
    add("Certificate", CERT_WORDS[cert.kind] ? `${cert.kind}: ${CERT_WORDS[cert.kind]}` : cert.kind);
    add("Re-checked in float64", cert.verified === null || cert.verified === undefined ? null : (cert.verified ? "yes" : "no"));
    add("What it proves", cert.statement);
    add("Relative margin", cert.margin !== null && cert.margin !== undefined ? fmt(cert.margin) : null);
    add("Smallest eigenvalue of P", cert.min_eig_P !== null && cert.min_eig_P !== undefined ? fmt(cert.min_eig_P) : null);
    add("Condition number of P", cert.condition_number ? fmt(cert.condition_number) : null);
    if (cert.eigenvalue) add("Unreached eigenvalue", `${fmt(cert.eigenvalue[0])} ${cert.eigenvalue[1] < 0 ? "-" : "+"} ${fmt(Math.abs(cert.eigenvalue[1]))}i of mode ${cert.plant + 1}`);
    if (cert.gain_bound !== undefined && cert.kind && cert.kind.startsWith("farkas")) add("Excludes gains of norm below", cert.gain_bound === null ? "any norm" : fmt(cert.gain_bound));
    add("Service's message", r.message);
    const det = el("details", { id: "proof-details" }, el("summary", { text: r.outcome === "stabilized" ? "The proof" : "The proof that no controller exists" }), dl);
    if (r.outcome !== "stabilized") det.open = true;
    $("proof").append(det);
  }
  if (r.outcome === "stabilized") renderNumbers(job);
  if (r.gains) renderGains(job);
  renderFigures(job);
  renderDownloads(job);
  box.focus();
}

function renderNumbers(job) {
  const r = job.result;
  const dl = el("dl", { class: "numbers" });
  const add = (k, v) => dl.append(el("dt", { text: k }), el("dd", { text: v }));
  if (r.decay_rate) {
    add("Decay rate", `${fmt(r.decay_rate)} per sample` + (r.exponential_rate ? ` (${fmt(r.exponential_rate)} 1/s, time constant ${fmt(r.time_constant)} s)` : ""));
  } else add("Decay rate", "none asked for: plain stability");
  const s = r.settling;
  if (s && s.samples !== null && s.samples !== undefined) {
    add("Certified settling", `${s.seconds !== null && s.seconds !== undefined ? fmt(s.seconds) + " s" : ""} (${s.samples} samples) to ${Math.round(100 * s.fraction)} % of |x(0)|, worst case over every allowed loss and switching pattern`);
  }
  if (r.rate_bracket && r.rate_bracket.fastest_certified) add("Fastest certifiable rate", fmt(r.rate_bracket.fastest_certified) + " per sample");
  add("Largest spectral radius of an interval loop", fmt(r.max_spectral_radius));
  const perf = r.performance;
  if (perf) {
    const gap = perf.gap !== null && perf.gap !== undefined ? `, gap ${(100 * perf.gap).toFixed(1)} %` : "";
    add(perf.kind === "hinf" ? "Worst-case l2 gain" : "Worst-case cost", `between ${perf.lower_infinite ? "infinity" : fmt(perf.lower)} and ${fmt(perf.upper)} (upper bound certified${gap})` + (perf.message ? `: ${perf.message}` : ""));
  }
  const ch = r.channel;
  if (ch) {
    add("Channel", `${ch.reason || ""} burst rate ${fmt(ch.burst_rate)} per sample` + (ch.mean_time_between_bursts_seconds ? `, one burst every ${fmt(ch.mean_time_between_bursts_seconds)} s on average` : "") +
      (ch.expected_cost !== null && ch.expected_cost !== undefined ? `, expected cost ${fmt(ch.expected_cost)}` : ""));
  }
  if (r.timings && r.timings.total !== undefined) add("Solve time", `${fmt(r.timings.total)} s, ${r.timings.solves || 1} SDP solve(s) with ${r.solver}`);
  $("numbers").append(el("h3", { text: "Numbers" }), dl);
}

function renderGains(job) {
  const r = job.result;
  const G = r.gains;
  const inputs = r.input_names || job.request?.plant?.input_names || G[0].map((_, i) => `u${i + 1}`);
  const states = r.state_names || job.request?.plant?.state_names || G[0][0].map((_, j) => `x${j + 1}`);
  const table = el("table", { id: "gains-table" });
  table.append(el("caption", { text: `Gains K1..K${G.length}` }));
  const head = el("tr", {}, el("th", { scope: "col", text: "gain" }), el("th", { scope: "col", text: "input" }));
  states.forEach((s) => head.append(el("th", { scope: "col", text: s })));
  table.append(el("thead", {}, head));
  const body = el("tbody");
  G.forEach((K, q) => K.forEach((row, i) => {
    const tr = el("tr", {}, el("th", { scope: "row", text: i === 0 ? `K${q + 1}` : "" }), el("td", { text: inputs[i] || `u${i + 1}` }));
    row.forEach((x) => tr.append(el("td", { text: fmt(x) })));
    body.append(tr);
  }));
  table.append(body);
  const asMatlab = G.map((K, q) => `K${q + 1} = ${matlab(K)};`).join("\n");
  const asNumpy = "import numpy as np\nK = np.array(" + JSON.stringify(G) + ")  # K[q-1] = K_q, shape (N, m, n)";
  const out = el("textarea", { id: "copy-out", rows: "3", readonly: "readonly", "aria-label": "Copied gains" });
  out.hidden = true;
  const copy = (text, what) => async () => {
    out.value = text;
    out.hidden = false;
    try { await navigator.clipboard.writeText(text); $("progress").textContent = `Gains copied as ${what}.`; }
    catch (e) { out.select(); $("progress").textContent = `Select and copy the ${what} text below.`; }
  };
  $("gains").append(el("h3", { text: "Gains" }),
    el("p", { class: "help", text: `After a packet with the state x(i) arrives, the actuator applies u(i + q - 1) = K_q x(i), q = 1..${G.length}, until the next one.` }),
    el("div", { class: "scroll" }, table),
    el("div", { class: "actions" }, el("button", { type: "button", id: "copy-matlab", on: copy(asMatlab, "MATLAB") }, "Copy as MATLAB"),
      el("button", { type: "button", id: "copy-numpy", on: copy(asNumpy, "NumPy") }, "Copy as NumPy")), out);
}

async function renderFigures(job) {
  const r = job.result || {};
  if (!r.gains) return;
  const fig = el("figure", {}, el("figcaption", { text: "Seeded simulation with the loss pattern (lost samples shaded); one column per plant mode." }));
  const marginBtn = el("button", { type: "button", id: "margin-curve" }, "Margin curve: the largest N with a design");
  marginBtn.addEventListener("click", () => marginCurve(job, marginBtn));
  const costBtn = el("button", { type: "button", id: "cost-curve" }, "Expected cost against loss probability");
  costBtn.addEventListener("click", () => costCurve(job, costBtn));
  $("figures").append(el("h3", { text: "Figures" }), fig, el("div", { class: "actions" }, marginBtn, costBtn));
  const x0 = job.request && job.request.x0 ? "&x0=" + job.request.x0.join(",") : "";
  const resp = await api("GET", `/v1/designs/${job.id}/trace.svg?width=1000&height=500${x0}`);
  if (resp.ok) {
    const url = URL.createObjectURL(await resp.blob());
    fig.prepend(el("img", { src: url, id: "trace-img", alt: "Simulated states and inputs over time for every plant mode, with lost packets marked" }));
  } else fig.append(el("p", { text: "The trace could not be drawn." }));
}

/** The expected cost E sum x'Qx + u'Ru (x(0) of covariance I) of the designed gains on independent losses of
 *  probability p, from POST /v1/channels (one call per p), drawn as an SVG. */
async function costCurve(job, btn) {
  btn.disabled = true;
  const status = el("p", { role: "status", text: "Computing the expected cost at each loss probability\u2026" });
  btn.parentNode.after(status);
  const r = job.result, req = job.request;
  const n = r.gains[0][0].length, m = r.gains[0].length;
  const weights = req.weights || { Q: parseMatrix(eye(n)), R: parseMatrix(eye(m)) };
  const ps = [0, 0.15, 0.3, 0.45, 0.6, 0.75, 0.9];
  const answers = await Promise.all(ps.map(async (p) => {
    const resp = await api("POST", "/v1/channels", { plant: req.plant, gains: r.gains, n_drop: req.n_drop,
      channel: { kind: "bernoulli", loss: p }, exhausted: req.exhausted || "hold", weights });
    return resp.ok ? resp.json() : null;
  }));
  const pts = ps.map((p, i) => [p, answers[i] && answers[i].ms_stable !== false ? answers[i].expected_cost_upper ?? answers[i].expected_cost : null]);
  const ok = pts.filter(([, c]) => c !== null && isFinite(c));
  if (!ok.length) { status.textContent = "No loss probability gave a finite expected cost."; return; }
  const W = 640, H = 300, L = 90, B = 50, T = 20, R = 20;
  const cmax = Math.max(...ok.map(([, c]) => c)) * 1.1, cmin = 0;
  const X = (p) => L + (p / 0.9) * (W - L - R), Y = (c) => H - B - ((c - cmin) / (cmax - cmin)) * (H - B - T);
  const NS = "http://www.w3.org/2000/svg";
  const svg = document.createElementNS(NS, "svg");
  svg.setAttribute("viewBox", `0 0 ${W} ${H}`);
  svg.setAttribute("role", "img");
  svg.setAttribute("id", "cost-svg");
  svg.setAttribute("aria-label", "Expected cost against loss probability: " + pts.map(([p, c]) => `p = ${p}: ${c === null ? "unstable" : fmt(c)}`).join(", "));
  const add = (tag, attrs, text) => {
    const e = document.createElementNS(NS, tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    if (text !== undefined) e.textContent = text;
    svg.append(e);
  };
  add("line", { x1: L, y1: H - B, x2: W - R, y2: H - B, stroke: "#1b1f24" });
  add("line", { x1: L, y1: T, x2: L, y2: H - B, stroke: "#1b1f24" });
  for (const p of [0, 0.3, 0.6, 0.9]) add("text", { x: X(p), y: H - B + 18, "text-anchor": "middle", "font-size": 12 }, String(p));
  for (const f of [0, 0.5, 1]) add("text", { x: L - 6, y: Y(cmin + f * (cmax - cmin)) + 4, "text-anchor": "end", "font-size": 12 }, fmt(cmin + f * (cmax - cmin)));
  add("text", { x: (L + W - R) / 2, y: H - 8, "text-anchor": "middle", "font-size": 13 }, "loss probability per sample");
  add("text", { x: 14, y: (T + H - B) / 2, "text-anchor": "middle", "font-size": 13, transform: `rotate(-90 14 ${(T + H - B) / 2})` }, "expected cost");
  add("polyline", { points: ok.map(([p, c]) => `${X(p)},${Y(c)}`).join(" "), fill: "none", stroke: "#0a58a8", "stroke-width": 2 });
  for (const [p, c] of pts) {
    if (c === null || !isFinite(c)) add("text", { x: X(p), y: T + 12, "text-anchor": "middle", "font-size": 12, fill: "#a3111b" }, "unstable");
    else add("circle", { cx: X(p), cy: Y(c), r: 3.5, fill: "#0a58a8" });
  }
  status.textContent = "Expected cost (certified upper bound) of these gains on independent losses; Q = " + (req.weights ? "your weights" : "I, R = I") + ".";
  status.after(el("figure", {}, svg, el("figcaption", { text: "Cost against loss probability (POST /v1/channels at each p)." })));
}

async function marginCurve(job, btn) {
  btn.disabled = true;
  const status = el("p", { role: "status", text: "Searching N = 1, 2, \u2026 (a margin job)\u2026" });
  btn.parentNode.after(status);
  const body = { plant: job.request.plant, search: "n_drop", method: job.request.method === "ccl" ? "lmi" : job.request.method, n_drop_max: 8 };
  const resp = await api("POST", "/v1/margins", body, { Prefer: "wait=60" });
  let m = await resp.json().catch(() => ({}));
  while (resp.ok && !["succeeded", "failed", "cancelled"].includes(m.status)) {
    const again = await api("GET", `/v1/margins/${m.id}`, undefined, { Prefer: "wait=30" });
    m = await again.json();
  }
  if (!resp.ok || m.status !== "succeeded") { status.textContent = `The margin search did not finish (${m.detail || m.status}).`; return; }
  const svg = await api("GET", `/v1/margins/${m.id}/curve.svg`);
  status.textContent = (m.result && m.result.message) || "Margin search done.";
  if (svg.ok) {
    const url = URL.createObjectURL(await svg.blob());
    status.after(el("figure", {}, el("img", { src: url, alt: "Designs tried at each N: certified or proven impossible" }),
      el("figcaption", { text: "Every N the search tried." })));
  }
}

function renderDownloads(job) {
  const r = job.result || {};
  const id = job.id;
  const files = [];
  if (job.status === "succeeded") {
    files.push(["gains.mat", `/v1/designs/${id}/gains.mat`, `ncs-design-${id}.mat`, "MATLAB .mat"]);
    files.push(["gains.m", `/v1/designs/${id}/gains.m`, `ncs-design-${id}.m`, "MATLAB/Octave script"]);
    if (r.gains) files.push(["controller.zip", `/v1/designs/${id}/controller.zip`, `ncs-controller-${id}.zip`, "C99 controller code (.zip)"]);
    const decay = ((job.request || {}).options || {}).decay_rate;
    // The SDP exists for lmi and switched; a rate search exports it at its certified rate, so it needs one.
    const sdp = job.request && job.request.method !== "ccl" && (!["max", "auto"].includes(decay) || r.decay_rate);
    if (sdp) files.push(["problem.dat-s", `/v1/designs/${id}/problem.dat-s`, `ncs-design-${id}.dat-s`, "the SDP (SDPA format)"]);
  }
  const list = el("ul", { class: "downloads" });
  for (const [name, path, filename, what] of files) {
    list.append(el("li", {}, el("button", { type: "button", "data-file": name, on: () => download(path, filename) }, `${name}`), ` ${what}`));
  }
  list.append(el("li", {}, el("button", { type: "button", "data-file": "job.json", on: () => saveBlob(new Blob([JSON.stringify(job, null, 1)], { type: "application/json" }), `ncs-design-${id}.json`) }, "job.json"), " the whole job (request and result)"));
  $("downloads").append(el("h3", { text: "Downloads" }), list);
}

// ---------------------------------------------------------------- past jobs
async function loadJobs() {
  let resp;
  try { resp = await fetch("/v1/designs?limit=20", { headers: headers() }); } catch (e) { return; }
  const list = $("jobs");
  if (!resp.ok) { list.replaceChildren(el("li", { text: resp.status === 401 ? "Enter the API key to see your jobs." : "Jobs could not be listed." })); return; }
  const data = await resp.json();
  list.replaceChildren();
  if (!data.items.length) list.append(el("li", { text: "No jobs yet." }));
  for (const j of data.items) {
    const p = j.plant || {};
    const plant = `${p.kind || "plant"}, n = ${p.n}, m = ${p.m}, ${p.r} mode${p.r === 1 ? "" : "s"}`;
    const outcome = j.status === "succeeded" ? (j.outcome || "succeeded") : j.status;
    const when = (j.created_at || "").replace("T", " ").slice(0, 19);
    list.append(el("li", {}, el("a", { href: "#job=" + j.id, text: j.label || j.id.slice(0, 8) }),
      ` \u2014 ${plant}, N = ${j.n_drop}, ${j.method}: `, el("span", { class: "outcome " + outcome, text: outcome }), ` (${when} UTC)`));
  }
}

// ---------------------------------------------------------------- plant files
async function loadPlantFile(file) {
  clearErrors();
  try {
    if (/\.mat$/i.test(file.name)) {
      const vars = await readMat(await file.arrayBuffer());
      const pick = (...ks) => ks.map((k) => vars[k]).find((v) => v);
      const A = pick("A", "F"), B = pick("B", "G");
      if (!A || !B) throw new Error(`no A and B (or F and G) in the file; it holds ${Object.keys(vars).join(", ") || "nothing"}`);
      const discrete = !vars.A;
      const req = { plant: { kind: discrete ? "discrete" : "continuous", [discrete ? "F" : "A"]: A, [discrete ? "G" : "B"]: B } };
      const h = vars.h || vars.sampling_period || vars.Ts;
      if (h) req.plant.sampling_period = h[0][0][0];
      fillForm(req);
    } else {
      const obj = JSON.parse(await file.text());
      fillForm(obj.plant ? obj : { plant: obj });
    }
    validateSoon();
  } catch (e) {
    showError("plant-file", `${file.name}: ${e.message}`);
  }
}

/** The numeric arrays of a MATLAB level 5 .mat file (compressed or not) as lists of modes of rows:
 *  an n x m x r array gives r matrices n x m, a matrix gives one. */
async function readMat(buf) {
  const out = {};
  const u8 = new Uint8Array(buf);
  if (u8.length < 128 || new TextDecoder().decode(u8.slice(0, 6)) !== "MATLAB") throw new Error("not a MATLAB 5 .mat file (save with -v7 or -v6)");
  const little = String.fromCharCode(u8[126], u8[127]) === "IM";
  const elements = async (bytes, at, end, cb) => {
    const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    while (at + 8 <= end) {
      let type = dv.getUint32(at, little), size, data;
      if (type >> 16) { size = type >> 16; type &= 0xffff; data = at + 4; at += 8; }
      else { size = dv.getUint32(at + 4, little); data = at + 8; at = data + size + ((8 - (size % 8)) % 8); }
      await cb(type, bytes.subarray(data, data + size));
      if (type === 15) at = data + size; // compressed elements are not padded
    }
  };
  const numeric = (type, b) => {
    const dv = new DataView(b.buffer, b.byteOffset, b.byteLength);
    const spec = { 1: [1, "getInt8"], 2: [1, "getUint8"], 3: [2, "getInt16"], 4: [2, "getUint16"], 5: [4, "getInt32"],
      6: [4, "getUint32"], 7: [4, "getFloat32"], 9: [8, "getFloat64"], 12: [8, "getBigInt64"], 13: [8, "getBigUint64"] }[type];
    if (!spec) throw new Error(`unsupported data type ${type}`);
    const vals = [];
    for (let i = 0; i + spec[0] <= b.length; i += spec[0]) vals.push(Number(dv[spec[1]](i, little)));
    return vals;
  };
  const matrix = async (b) => {
    const parts = [];
    await elements(b, 0, b.length, async (t, d) => { parts.push([t, d]); });
    const dims = numeric(parts[1][0], parts[1][1]);
    const name = new TextDecoder().decode(parts[2][1]);
    const cls = parts[0][1][0];
    if (cls < 6 || cls > 15) return; // not a numeric array (cell, struct, char...)
    const re = numeric(parts[3][0], parts[3][1]);
    const [n, m, r] = [dims[0], dims[1], dims[2] || 1];
    const modes = [];
    for (let l = 0; l < r; l++) {
      modes.push(Array.from({ length: n }, (_, i) => Array.from({ length: m }, (_, j) => re[i + n * j + n * m * l])));
    }
    out[name] = modes;
  };
  await elements(u8, 128, u8.length, async (type, data) => {
    if (type === 14) await matrix(data);
    else if (type === 15) {
      const ds = new Blob([data]).stream().pipeThrough(new DecompressionStream("deflate"));
      const inner = new Uint8Array(await new Response(ds).arrayBuffer());
      await elements(inner, 0, inner.length, async (t, d) => { if (t === 14) await matrix(d); });
    }
  });
  return out;
}

// ---------------------------------------------------------------- schema-driven parts
async function readSchema() {
  try {
    const resp = await fetch("/openapi.json");
    state.schema = await resp.json();
  } catch (e) { return; }
  const schemas = (state.schema.components || {}).schemas || {};
  const dr = schemas.DesignRequest || {};
  const props = dr.properties || {};
  const resolve = (s) => (s && s.$ref ? schemas[s.$ref.split("/").pop()] : s);
  const method = resolve(props.method);
  if (method && method.enum) {
    const cur = $("method").value;
    $("method").replaceChildren(...method.enum.map((v) => el("option", { value: v, text: v })));
    $("method").value = method.enum.includes(cur) ? cur : method.enum[0];
  }
  // A `network` field appears in the form only when the service's DesignRequest has one.
  const net = resolve(props.network);
  if (net) {
    const values = [];
    const walk = (s) => {
      s = resolve(s);
      if (!s) return;
      if (s.enum) s.enum.forEach((v) => values.push(v));
      if (s.const !== undefined) values.push(s.const);
      (s.anyOf || s.oneOf || []).forEach(walk);
    };
    walk(net);
    const sel = $("network");
    sel.replaceChildren(el("option", { value: "", text: `default${net.default !== undefined ? " (" + JSON.stringify(net.default) + ")" : ""}` }));
    values.filter((v) => v !== null).forEach((v) => sel.append(el("option", { value: typeof v === "string" ? v : JSON.stringify(v), text: typeof v === "string" ? v : JSON.stringify(v) })));
    $("help-network").textContent = (net.description || props.network.description || "").replace(/`/g, "");
    if (!values.filter((v) => v !== null).length) { // not a choice among names: JSON as the schema describes it
      sel.hidden = true;
      $("network_json").hidden = false;
      $("network-row").querySelector("label").setAttribute("for", "network_json");
    }
    $("network-row").hidden = false;
  }
}

// ---------------------------------------------------------------- start
async function start() {
  $("api_key").value = sessionStorage.getItem("ncs-api-key") || "";
  $("api_key").addEventListener("change", () => { sessionStorage.setItem("ncs-api-key", $("api_key").value.trim()); loadJobs(); });
  document.querySelectorAll("input[name=kind]").forEach((r) => r.addEventListener("change", () => { setKind(plantKind()); validateSoon(); }));
  $("add-mode").addEventListener("click", () => { const d = addMode("", "", ""); d.querySelector(".mat-A").focus(); });
  $("decay").addEventListener("change", () => { $("decay_value").disabled = $("decay").value !== "number"; });
  $("channel").addEventListener("change", showChannel);
  $("objective").addEventListener("change", () => { $("weights").hidden = $("objective").value !== "cost"; });
  $("design").addEventListener("input", (ev) => { if (ev.target.id !== "api_key" && ev.target.id !== "plant-file") validateSoon(); });
  $("design").addEventListener("submit", submit);
  $("cancel").addEventListener("click", cancelJob);
  $("refresh-jobs").addEventListener("click", loadJobs);
  $("plant-file").addEventListener("change", () => { const f = $("plant-file").files[0]; if (f) loadPlantFile(f); });
  $("load-example").addEventListener("click", () => {
    const ex = state.examples.find((e) => e.id === $("example").value);
    if (ex) { fillForm(ex.request); $("progress").textContent = `Loaded: ${ex.title}.`; }
    else { fillForm({ plant: { kind: "continuous", sampling_period: 0.1 } }); }
  });
  addMode("", "", "");
  try {
    state.examples = await (await fetch("/static/page/examples.json")).json();
    for (const e of state.examples) $("example").append(el("option", { value: e.id, text: e.title }));
  } catch (e) { /* the form works without examples */ }
  await readSchema();
  loadJobs();
  route();
  window.addEventListener("hashchange", route);
  document.body.dataset.ready = "1";
}

function route() {
  const m = /^#job=([\w-]+)$/.exec(location.hash);
  if (m && (!state.job || state.job.id !== m[1] || !state.stream)) {
    if (state.job && state.job.id === m[1] && state.job.result) return;
    state.job = { id: m[1] };
    watch(m[1]);
  }
}

document.addEventListener("DOMContentLoaded", start);
