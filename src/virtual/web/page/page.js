// The commissioning page. Plain script, no libraries: it reads the drive's
// view from /api/state, the scope samples from /api/events (server-sent
// events) and sends every action to /api/cmd, which turns it into Modbus
// requests through the drive's dispatcher.
"use strict";

const $ = (id) => document.getElementById(id);
const WINDOW_S = 10;

// SPEC §8.2; bits 12 and 13 depend on the mode.
const SW_BITS = [
  "ready to switch on", "switched on", "operation enabled", "fault",
  "voltage enabled", "quick stop (0 = active)", "switch on disabled",
  "warning: motion refused", "halt active", "motor running",
  "target reached", "home switch active", null, null,
  "CW limit active", "CCW limit active",
];
const SW_MODE_BITS = {
  1: ["set-point can be accepted", "following error"],
  3: ["speed is 0", "at the acceleration limit"],
  6: ["homing attained", "homing error"],
};
const SW_ALARM = new Set([3, 7, 13, 14, 15]);
// SPEC §8.7.
const ER_BITS = ["generic", "current", "voltage", "temperature", "communication",
  "following error", "reserved", "motor phase loss"];
// SPEC §5.2.
const EXCEPTIONS = {
  1: "illegal function", 2: "illegal data address", 3: "illegal data value",
  4: "device failure", 5: "write to read-only", 6: "busy", 7: "read of write-only",
  8: "byte count does not match", 9: "parity error", 10: "CRC error",
  11: "register does not exist",
};
const MODES = { 0: "no mode", 1: "position", 3: "velocity", 6: "homing" };
const COUNTERS = [
  ["bus_messages", "bus messages (0x0B)"], ["bus_errors", "bus errors (0x0C)"],
  ["exceptions", "exceptions (0x0D)"], ["slave_messages", "slave messages (0x0E)"],
  ["no_response", "no response (0x0F)"], ["busy", "busy (0x11)"],
  ["overruns", "overruns (0x12)"],
];

const hex4 = (v) => "0x" + (v & 0xffff).toString(16).toUpperCase().padStart(4, "0");
const excText = (c) => `exception ${c} (${EXCEPTIONS[c] || "?"})`;

let drive = 0;
let lastState = null;

// ---- commands ----------------------------------------------------------

async function cmd(params) {
  const q = new URLSearchParams({ d: drive, ...params });
  let r;
  try {
    const res = await fetch("/api/cmd?" + q, {
      method: "POST",
      headers: { "X-Modbus-Drive": "page" },
    });
    r = await res.json();
  } catch (e) {
    r = { ok: false, error: String(e), steps: [] };
  }
  showResult(r, params.c);
  return r;
}

// One line per request: what it was for, the frame, the drive's answer.
function describe(r) {
  const lines = r.steps.map((s) => {
    const a = s.answer === "ok" ? "ok" : s.answer === "exception" ? excText(s.code) : s.answer;
    return `${s.label}: ${a}\n  → ${s.request}` + (s.reply ? `\n  ← ${s.reply}` : "");
  });
  if (r.error) lines.push(r.error);
  return lines.join("\n");
}

// Short form for a table row: ✓ or the exception.
function verdict(r) {
  const bad = r.steps.find((s) => s.answer !== "ok");
  if (bad && bad.answer === "exception") return { ok: false, text: excText(bad.code) };
  if (bad) return { ok: false, text: bad.answer };
  if (!r.ok) return { ok: false, text: r.error || "refused" };
  return { ok: true, text: "✓ written" };
}

function showResult(r, name) {
  const log = $("cmd-log");
  const v = verdict(r);
  log.textContent = `${name}: ${r.ok ? "done" : "refused"}\n` + describe(r);
  log.className = "log " + (v.ok ? "" : "exc-box");
  log.dataset.ok = r.ok ? "1" : "0";
}

const profile = () => ({ speed: $("speed").value || 0, accel: $("accel").value || 0 });

function wireControls() {
  const simple = { enable: "enable", disable: "disable", reset: "reset", halt: "halt",
    quickstop: "quickstop", home: "home" };
  for (const [id, c] of Object.entries(simple)) $(id).onclick = () => cmd({ c });
  // On a real drive the saved set is what it boots with: ask first.
  $("save").onclick = () => {
    if (!remote() || confirm("Save the working parameters to the drive's flash (EE-Set)?")) cmd({ c: "save" });
  };
  $("defaults").onclick = () => {
    if (confirm("Restore the factory defaults and save them (EE-dEF)? Every parameter is replaced.")) cmd({ c: "defaults" });
  };
  $("move-go").onclick = () => cmd({
    c: "move", target: $("move-target").value || 0,
    relative: $("move-relative").checked ? 1 : 0, ...profile(),
  });
  for (const [id, dir] of [["jog-neg", "neg"], ["jog-pos", "pos"]]) {
    const b = $(id);
    let jogging = false;
    const start = (e) => { e.preventDefault(); jogging = true; b.classList.add("active"); cmd({ c: "jog", dir, ...profile() }); };
    const stop = () => { if (!jogging) return; jogging = false; b.classList.remove("active"); cmd({ c: "jogstop" }); };
    b.addEventListener("pointerdown", start);
    b.addEventListener("pointerup", stop);
    b.addEventListener("pointerleave", stop);
  }
  for (const tr of document.querySelectorAll("#switches tr")) {
    const cell = tr.querySelector(".force");
    for (const s of ["auto", "on", "off"]) {
      const b = document.createElement("button");
      b.textContent = s;
      b.dataset.state = s;
      b.onclick = () => cmd({ c: "force", switch: tr.dataset.switch, state: s });
      cell.append(b);
    }
  }
  $("raw-send").onclick = async () => {
    const pdu = $("raw-pdu").value.replace(/[^0-9a-fA-F]/g, "");
    const r = await cmd({ c: "raw", pdu });
    $("raw-log").textContent = describe(r);
  };
  $("drive").onchange = (e) => { drive = Number(e.target.value); buildTables(); };
}

// ---- status ------------------------------------------------------------

function bits(ul, count, names, value, alarm) {
  if (ul.children.length !== count) {
    ul.textContent = "";
    for (let i = 0; i < count; i++) {
      const li = document.createElement("li");
      li.innerHTML = `<b>${i}</b><span></span>`;
      ul.append(li);
    }
  }
  for (let i = 0; i < count; i++) {
    const li = ul.children[i];
    li.lastChild.textContent = names[i] || "—";
    li.classList.toggle("set", ((value >> i) & 1) === 1);
    li.classList.toggle("alarm", alarm.has(i));
    li.dataset.bit = i;
  }
}

function renderStatus(d) {
  $("state").textContent = d.state.replace(/([a-z])([A-Z])/g, "$1 $2");
  $("mode").textContent = `${MODES[d.mode] ?? d.mode} (${d.mode})`;
  $("address").textContent = d.address;
  // The readouts come from the same snapshot as the state and the
  // statusword bits, so that they never disagree (the scope's stream runs
  // on its own and may lag behind under load).
  $("pos-readout").textContent = d.position;
  $("vel-readout").textContent = d.velocity;
  if (d.following_error !== null) $("fe-readout").textContent = d.following_error;
  $("sw-hex").textContent = hex4(d.statusword);
  $("er-hex").textContent = hex4(d.error_register);
  const names = SW_BITS.slice();
  const mb = SW_MODE_BITS[d.mode] || ["bit 12 (mode specific)", "bit 13 (mode specific)"];
  names[12] = mb[0];
  names[13] = mb[1];
  bits($("sw-bits"), 16, names, d.statusword, SW_ALARM);
  bits($("er-bits"), 8, ER_BITS, d.error_register, new Set([0, 1, 2, 3, 4, 5, 7]));
  for (const tr of document.querySelectorAll("#switches tr")) {
    const s = tr.dataset.switch;
    tr.querySelector(".lamp").classList.toggle("set", d.switches[s]);
    const f = tr.querySelector(".force");
    f.hidden = !d.forced;
    if (!d.forced) continue;
    const forced = d.forced[s] === null ? "auto" : d.forced[s] ? "on" : "off";
    for (const b of tr.querySelectorAll(".force button")) b.classList.toggle("sel", b.dataset.state === forced);
  }
  const tb = $("counters").tBodies[0];
  tb.innerHTML = COUNTERS.map(([k, n]) =>
    `<tr><td>${n}</td><td data-counter="bus-${k}">${d.bus_counters[k]}</td><td data-counter="page-${k}">${d.page_counters ? d.page_counters[k] : "—"}</td></tr>`).join("");
  $("listen-only").hidden = !d.listen_only;
  $("switches-title").textContent = d.forced ? "Switches of the simulated axis" : "Switch inputs (DP-In)";
  const rm = $("remote");
  rm.hidden = !d.link;
  if (d.link) {
    rm.textContent = `${d.link.describe}, address ${d.link.address}: ${d.link.rate} samples/s` +
      (d.link.error ? ` — not answering: ${d.link.error}` : "");
    rm.className = d.link.ok ? "" : "exc";
  }
  setLink(scope.connected);
  const eb = $("exceptions").tBodies[0];
  eb.innerHTML = d.exceptions.slice().reverse().map((e) =>
    `<tr><td>${e.t.toFixed(2)}</td><td>${e.port}</td><td>0x${e.function.toString(16).toUpperCase().padStart(2, "0")}</td>` +
    `<td class="exc">${e.code} ${EXCEPTIONS[e.code] || ""}${e.answered ? "" : " (not answered)"}</td></tr>`).join("");
}

// The Modbus TCP server's connection counters (absent without --modbus-tcp).
function renderModbusTcp(m) {
  const p = $("modbus-tcp");
  p.hidden = !m;
  if (!m) return;
  const idle = m.idle_timeout_s === null ? "never" : `${m.idle_timeout_s} s`;
  p.textContent = `Modbus TCP: ${m.connections} connected, ${m.requests} requests, ` +
    `${m.bad_adus} bad ADUs; closed idle (${idle}): ${m.idle_closed}, ` +
    `closed to admit a new client: ${m.evicted}, refused: ${m.refused}`;
}

// ---- dictionary and PA tables ------------------------------------------

function rowHtml(key, cells, writable) {
  const edit = writable
    ? `<input type="text" inputmode="numeric" aria-label="new value"></td><td><button>Write</button> <span class="result"></span>`
    : `</td><td>`;
  return `<tr data-index="${key}" class="${writable ? "" : "ro"}">${cells.map((c) => `<td>${c}</td>`).join("")}<td class="value"></td><td>${edit}</td></tr>`;
}

function buildTables() {
  const d = lastState && lastState.drives[drive];
  if (!d) return;
  $("od").tBodies[0].innerHTML = d.od.map((e) =>
    rowHtml(e.index, [hex4(e.index), e.name, e.access, e.type, e.range, e.unit], e.access !== "RO")).join("");
  $("pa").tBodies[0].innerHTML = d.pa.map((p) =>
    rowHtml(0x64 + p.n, [`PA${p.n}`, p.name, p.access, "U16", `${p.min}..=${p.max}`, p.unit], p.access !== "RO")).join("");
  for (const tr of document.querySelectorAll(".params tbody tr")) {
    const b = tr.querySelector("button");
    if (!b) continue;
    const input = tr.querySelector("input");
    const write = async () => {
      const res = tr.querySelector(".result");
      res.textContent = "…";
      const value = input.value.trim();
      const r = await cmd({ c: "write", index: tr.dataset.index, value });
      const v = verdict(r);
      res.textContent = v.text;
      res.className = "result " + (v.ok ? "okmsg" : "exc");
    };
    b.onclick = write;
    input.onkeydown = (e) => { if (e.key === "Enter") write(); };
  }
  $("fe-row").hidden = d.following_error === null;
}

function renderTables(d) {
  const fill = (id, list) => {
    const rows = $(id).tBodies[0].rows;
    list.forEach((e, i) => {
      const cell = rows[i] && rows[i].querySelector(".value");
      if (!cell) return;
      let v = e.value;
      if (v !== null && typeof v === "object") v = `${v.written} (last written; reads give exception 7)`;
      if (v === null) v = "…"; // not read yet (the page over a Modbus master)
      cell.textContent = v;
    });
  };
  fill("od", d.od);
  fill("pa", d.pa);
}

async function pollState() {
  try {
    const res = await fetch("/api/state", { cache: "no-store" });
    const s = await res.json();
    const first = !lastState;
    lastState = s;
    const sel = $("drive");
    if (sel.options.length !== s.drives.length) {
      sel.innerHTML = s.drives.map((d, i) => `<option value="${i}">${i}: address ${d.address}</option>`).join("");
      sel.value = drive;
    }
    const d = s.drives[drive];
    if (first || $("od").tBodies[0].rows.length !== d.od.length) buildTables();
    renderStatus(d);
    renderTables(d);
    renderModbusTcp(s.modbus_tcp);
  } catch (e) {
    // The drive stopped or is restarting: keep trying.
  }
  setTimeout(pollState, 200);
}

// ---- scope ---------------------------------------------------------------

// Per drive: samples [t, position, velocity, following error | null, statusword].
const scope = {
  buf: [], frozen: null, span: WINDOW_S, end: null, samples: 0, rate: 0, connected: false,
};
window.scope = scope;

function connectEvents() {
  const es = new EventSource("/api/events");
  es.onopen = () => { scope.connected = true; setLink(true); };
  es.onerror = () => { scope.connected = false; setLink(false); };
  es.onmessage = (ev) => {
    const batch = JSON.parse(ev.data);
    for (const s of batch) {
      const t = s[0];
      for (let i = 1; i < s.length; i++) {
        const b = scope.buf[i - 1] || (scope.buf[i - 1] = []);
        const [p, v, fe, sw] = s[i];
        b.push([t, p, v, fe, sw]);
      }
      scope.samples++;
    }
    for (const b of scope.buf) {
      const cut = b.length ? b[b.length - 1][0] - WINDOW_S : 0;
      let n = 0;
      while (n < b.length && b[n][0] < cut) n++;
      if (n) b.splice(0, n);
    }
  };
}

// A page over a Modbus master (`commission`) knows the drive behind it.
const remote = () => !!(lastState && lastState.drives[drive] && lastState.drives[drive].link);

function setLink(on) {
  const l = $("link");
  const d = lastState && lastState.drives[drive];
  const gone = on && d && d.link && !d.link.ok;
  l.textContent = !on ? "disconnected" : gone ? "drive not answering" : "live";
  l.className = "pill " + (on && !gone ? "ok" : "off");
}

setInterval(() => {
  scope.rate = scope.samples;
  scope.samples = 0;
  $("rate").textContent = `${scope.rate} samples/s`;
}, 1000);

function shown() {
  return (scope.frozen || scope.buf[drive] || []);
}

function scopeCsv() {
  const data = shown();
  const fe = data.some((r) => r[3] !== null);
  const head = ["time_s", "position_steps", "velocity_rpm"].concat(fe ? ["following_error_steps"] : [], ["statusword"]);
  const rows = data.map((r) => [r[0].toFixed(3), r[1], r[2]].concat(fe ? [r[3]] : [], [hex4(r[4])]).join(","));
  return head.join(",") + "\n" + rows.join("\n") + "\n";
}
window.scopeCsv = scopeCsv;

function downloadCsv() {
  const blob = new Blob([scopeCsv()], { type: "text/csv" });
  const a = document.createElement("a");
  a.href = URL.createObjectURL(blob);
  a.download = `scope-drive${drive}.csv`;
  a.click();
  setTimeout(() => URL.revokeObjectURL(a.href), 1000);
}

function wireScope() {
  const c = $("scope");
  $("pause").onclick = () => {
    if (scope.frozen) {
      scope.frozen = null;
      scope.end = null;
      $("pause").textContent = "Pause";
    } else {
      scope.frozen = (scope.buf[drive] || []).slice();
      $("pause").textContent = "Resume";
    }
  };
  for (const b of document.querySelectorAll("button.span")) b.onclick = () => { scope.span = Number(b.dataset.span); };
  $("csv").onclick = downloadCsv;
  c.addEventListener("wheel", (e) => {
    e.preventDefault();
    scope.span = Math.min(WINDOW_S, Math.max(0.05, scope.span * (e.deltaY > 0 ? 1.25 : 0.8)));
  }, { passive: false });
  let drag = null;
  c.addEventListener("pointerdown", (e) => { if (scope.frozen) drag = { x: e.clientX, end: viewEnd() }; });
  c.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const dt = (e.clientX - drag.x) / c.clientWidth * scope.span;
    scope.end = drag.end - dt;
  });
  window.addEventListener("pointerup", () => { drag = null; });
}

function viewEnd() {
  const d = shown();
  const last = d.length ? d[d.length - 1][0] : 0;
  return scope.frozen && scope.end !== null ? scope.end : last;
}

const TRACES = [
  { col: 1, name: "position", unit: "steps", color: "#60a5fa" },
  { col: 2, name: "velocity", unit: "r/min", color: "#34d399" },
  { col: 3, name: "following error", unit: "steps", color: "#f87171" },
];

function draw() {
  const c = $("scope");
  const ctx = c.getContext("2d");
  const W = c.width, H = c.height;
  ctx.fillStyle = "#0b1220";
  ctx.fillRect(0, 0, W, H);
  const data = shown();
  const end = viewEnd();
  const start = end - scope.span;
  const view = data.filter((r) => r[0] >= start && r[0] <= end);
  const traces = TRACES.filter((t) => t.col !== 3 || data.some((r) => r[3] !== null));
  const left = 70, right = 10, gap = 8;
  const h = (H - 24 - gap * (traces.length - 1)) / traces.length;
  ctx.font = "12px system-ui, sans-serif";
  traces.forEach((t, k) => {
    const top = k * (h + gap);
    let lo = Infinity, hi = -Infinity;
    for (const r of view) { lo = Math.min(lo, r[t.col]); hi = Math.max(hi, r[t.col]); }
    if (!isFinite(lo)) { lo = -1; hi = 1; }
    if (hi - lo < 1e-9) { lo -= 1; hi += 1; }
    const pad = (hi - lo) * 0.08;
    lo -= pad; hi += pad;
    const x = (tt) => left + (tt - start) / scope.span * (W - left - right);
    const y = (v) => top + h - 6 - (v - lo) / (hi - lo) * (h - 12);
    ctx.strokeStyle = "#1f2a3d";
    ctx.lineWidth = 1;
    ctx.strokeRect(left, top, W - left - right, h);
    ctx.fillStyle = "#94a3b8";
    for (let i = 0; i <= 4; i++) {
      const v = lo + (hi - lo) * i / 4;
      const yy = y(v);
      ctx.strokeStyle = "#172033";
      ctx.beginPath(); ctx.moveTo(left, yy); ctx.lineTo(W - right, yy); ctx.stroke();
      ctx.fillText(Math.round(v).toString(), 4, yy + 4);
    }
    ctx.fillStyle = t.color;
    ctx.fillText(`${t.name} (${t.unit})`, left + 6, top + 14);
    ctx.strokeStyle = t.color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    view.forEach((r, i) => {
      const px = x(r[0]), py = y(r[t.col]);
      if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
    });
    ctx.stroke();
  });
  ctx.fillStyle = "#94a3b8";
  // Time relative to the right edge; the edge's own time since start.
  for (let i = 0; i < 5; i++) {
    const dt = scope.span * (i - 5) / 5;
    const px = left + (W - left - right) * i / 5;
    ctx.fillText(`${dt.toFixed(scope.span < 1 ? 2 : 1)} s`, px - 12, H - 6);
  }
  ctx.fillText(`t = ${end.toFixed(2)} s`, W - right - 80, H - 6);
  if (scope.frozen) { ctx.fillStyle = "#fbbf24"; ctx.fillText("PAUSED", W - 70, 14); }
  scope.drawn = (scope.drawn || 0) + 1;
  requestAnimationFrame(draw);
}

wireControls();
wireScope();
connectEvents();
pollState();
requestAnimationFrame(draw);
