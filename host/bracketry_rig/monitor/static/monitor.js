// The monitor page: polls the JSON endpoints (about 1 Hz) and updates the page in place. No external code.
"use strict";
const params = new URLSearchParams(window.location.search);
const token = params.get("token") || "";
const q = token ? "token=" + encodeURIComponent(token) : "";
let suggested = null;
let updates = 0;

function withToken(url) { return q ? url + (url.includes("?") ? "&" : "?") + q : url; }

async function getJSON(url) {
  const r = await fetch(withToken(url), {cache: "no-store"});
  if (!r.ok) throw new Error(url + ": HTTP " + r.status);
  return r.json();
}

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

function fmtDuration(s) {
  if (s === null || s === undefined) return "–";
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = Math.floor(s % 60);
  return (h ? h + " h " : "") + (h || m ? m + " min " : "") + (h ? "" : sec + " s");
}

function showStatus(st) {
  const rec = document.getElementById("rec");
  rec.textContent = st.recording.active ? "REC " + fmtDuration(st.recording.seconds) + " seg " + st.recording.segment
    : (st.sensors_on ? "IDLE" : "OFF");
  rec.className = "badge " + (st.recording.active ? "REC" : "");
  document.getElementById("message").textContent = st.message;
  const left = st.disk.time_left_s === null ? "" : ", " + fmtDuration(st.disk.time_left_s) + " left";
  document.getElementById("disk").textContent = "disk " + (st.disk.free_mb / 1024).toFixed(1) + " GB free" + left;
  const sensors = document.getElementById("sensors");
  sensors.replaceChildren();
  for (const [name, state] of Object.entries(st.sensors)) {
    const s = el("span", "sensor " + state, name + " " + state);
    s.id = "state-" + name;
    if (st.errors[name]) s.title = st.errors[name];
    sensors.appendChild(s);
  }
  for (const [side, cam] of Object.entries(st.cameras)) {
    const box = document.querySelector("#cam-" + side + " .camstat");
    if (!box) continue;
    const temp = cam.temperature_c === null ? "–" : cam.temperature_c + " °C";
    box.textContent = cam.state + " · " + cam.fps.toFixed(1) + " fps · frames " + cam.frames + " · drops " +
      cam.drops + " · " + temp;
    box.dataset.state = cam.state;
    box.dataset.frames = cam.frames;
  }
}

function drawHistogram(canvas, hist) {
  const w = canvas.width = hist.length * 2, h = canvas.height = 40;
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, w, h);
  const top = Math.max(1, ...hist.map((v) => Math.log1p(v)));
  hist.forEach((v, i) => {
    const bar = h * Math.log1p(v) / top;
    ctx.fillStyle = i === 0 ? "#f55" : (i === hist.length - 1 ? "#58f" : "#ccc");
    ctx.fillRect(i * 2, h - bar, 2, bar);
  });
}

function showPreviews(pv) {
  for (const [side, list] of Object.entries(pv.cameras)) {
    const grid = document.querySelector("#cam-" + side + " .brackets");
    if (!grid) continue;
    const want = new Set(list.map((p) => String(p.bracket)));
    for (const child of [...grid.children]) if (!want.has(child.dataset.bracket)) child.remove();
    for (const p of list) {
      let box = grid.querySelector('[data-bracket="' + p.bracket + '"]');
      if (!box) {
        box = el("div", "bracket");
        box.dataset.bracket = p.bracket;
        box.appendChild(el("img"));
        box.appendChild(el("canvas"));
        box.appendChild(el("div", "cap"));
        grid.appendChild(box);
      }
      if (box.dataset.version !== String(p.version)) {
        box.dataset.version = p.version;
        box.querySelector("img").src = withToken(p.url);
        box.querySelector("img").alt = side + " bracket " + p.bracket;
        drawHistogram(box.querySelector("canvas"), p.histogram);
      }
      box.querySelector(".cap").textContent = (p.exposure_us / 1000).toFixed(3) + " ms · sat " +
        (100 * p.over).toFixed(1) + "% · dark " + (100 * p.under).toFixed(1) + "%";
    }
  }
}

function showAdvice(a) {
  const box = document.getElementById("advice");
  if (!a.rig) { suggested = null; document.getElementById("apply").disabled = true; return; }
  const r = a.rig;
  const ms = (us) => (us / 1000).toFixed(3);
  let text = "scene " + r.dynamic_range_stops.toFixed(1) + " stops" + (r.clipped_share > 0.005 ? " (at least)" : "") +
    "; current table [" + a.brackets_us.map(ms).join(", ") + "] ms covers " + (100 * r.coverage).toFixed(1) +
    "%; suggested [" + r.suggested_us.map(ms).join(", ") + "] ms would cover " +
    (100 * r.suggested_coverage).toFixed(1) + "%";
  for (const [side, c] of Object.entries(a.cameras)) {
    text += " · " + side + ": " + c.dynamic_range_stops.toFixed(1) + " stops, " + (100 * c.coverage).toFixed(1) + "%";
  }
  box.textContent = text;
  suggested = r.suggested_us;
  document.getElementById("apply").disabled = !token;
}

async function act(action, extra) {
  const out = document.getElementById("action-result");
  try {
    const r = await fetch("/api/action", {method: "POST", headers: {"Content-Type": "application/json",
      "X-Bracketry-Token": token}, body: JSON.stringify(Object.assign({action: action}, extra || {}))});
    const body = await r.json();
    out.textContent = r.ok ? action + ": done" : action + ": " + (body.error || "HTTP " + r.status);
  } catch (e) {
    out.textContent = action + ": " + e;
  }
}

async function tick() {
  try {
    const [st, pv] = await Promise.all([getJSON("/api/status"), getJSON("/api/previews")]);
    showStatus(st);
    showPreviews(pv);
    updates += 1;
    const u = document.getElementById("updated");
    u.dataset.count = updates;
    u.textContent = "updated " + new Date().toLocaleTimeString();
  } catch (e) {
    document.getElementById("updated").textContent = "no answer: " + e.message;
  }
}

async function tickAdvisor() {
  try { showAdvice(await getJSON("/api/advisor")); } catch (e) { /* shown by tick() */ }
}

// A board capture (bracketry calibrate capture): the latest pair with its corners (green: kept, orange: not),
// the coverage bars (x, y, size, skew as ROS camera_calibration) and whether the set is enough.
let calVersion = -1;

function drawCorners(side, cal) {
  const canvas = document.getElementById("cal-" + side);
  const img = new Image();
  img.onload = () => {
    canvas.width = img.naturalWidth;
    canvas.height = img.naturalHeight;
    const ctx = canvas.getContext("2d");
    ctx.drawImage(img, 0, 0);
    const pts = (cal.last && cal.last.corners[side]) || [];
    ctx.fillStyle = cal.last && cal.last.kept ? "#3f3" : "#fa3";
    for (const [x, y] of pts) ctx.fillRect(x * canvas.width - 2, y * canvas.height - 2, 4, 4);
    canvas.dataset.corners = pts.length;
    canvas.dataset.version = cal.version;
  };
  img.src = withToken("/api/calibration/" + side + ".png?v=" + cal.version);
}

function showCalibration(cal) {
  const box = document.getElementById("calibration");
  if (!cal.active) { box.hidden = true; return; }
  box.hidden = false;
  for (const [name, v] of Object.entries(cal.bars)) {
    const bar = document.querySelector('#cal-bars [data-param="' + name + '"]');
    bar.querySelector("progress").value = v;
    bar.querySelector(".val").textContent = Math.round(100 * v) + "%";
    bar.dataset.value = v;
  }
  const badge = document.getElementById("cal-enough");
  badge.textContent = cal.enough ? "ENOUGH" : cal.kept + " kept";
  badge.className = "badge" + (cal.enough ? " ok" : "");
  const last = cal.last ? (cal.last.kept ? "last pair kept" : "last pair: " + cal.last.why) : "no pair yet";
  document.getElementById("cal-info").textContent = cal.kept + " views kept of " + cal.offered + " pairs; " + last +
    (cal.done ? "; capture ended" : "");
  document.getElementById("cal-advice").textContent = cal.advice;
  box.dataset.kept = cal.kept;
  box.dataset.enough = cal.enough;
  if (cal.version !== calVersion && cal.last) {
    calVersion = cal.version;
    drawCorners("left", cal);
    drawCorners("right", cal);
  }
}

async function tickCalibration() {
  try { showCalibration(await getJSON("/api/calibration")); } catch (e) { /* shown by tick() */ }
}

document.getElementById("apply").onclick = () => suggested && act("apply_brackets", {brackets_us: suggested});
document.getElementById("sensors-on").onclick = () => act("sensors_on");
document.getElementById("sensors-off").onclick = () => act("sensors_off");
document.getElementById("record-start").onclick = () => act("record_start");
document.getElementById("record-stop").onclick = () => act("record_stop");
if (!token) for (const b of document.querySelectorAll("button")) b.disabled = true;
tick();
tickAdvisor();
tickCalibration();
setInterval(tick, 1000);
setInterval(tickCalibration, 1000);
setInterval(tickAdvisor, 3000);
