// The operator's page (trackcal/campaign/web). Everything it shows comes from the server's event stream:
// a snapshot folded from the session's events when it (re)connects, then patches; nothing is kept across a
// reload but this tab's client id (sessionStorage), so a reload keeps control.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const LOST_AFTER_MS = 3500;  // the server sends a heartbeat every second (app.py HEARTBEAT_S)
const RECONNECT_MS = 2000;  // a refused stream (a restarted server, too many pages open) is asked for again
const COLORS = ["#1f5fa8", "#c0582b", "#2c8a4b", "#7a3da0", "#a8871f", "#2b8a8a"];

const page = { view: null, points: [], plan: null, live: {}, csrf: "", connected: false, heard: 0, pending: false,
               answered: null, fresh: [], plotDirty: true, fitsShown: null };
window.trackcalSeen = {};  // event id of a measurement -> when it was drawn (bench/bench_web.py reads it)
window.trackcalFitsSeen = {};  // event id of a station fit -> when its residuals were drawn (bench/bench_web.py)

function clientId() {
  let id = sessionStorage.getItem("trackcal-client");
  if (!id) {
    const b = new Uint8Array(12);
    crypto.getRandomValues(b);
    id = Array.from(b, (x) => x.toString(16).padStart(2, "0")).join("");
    sessionStorage.setItem("trackcal-client", id);
  }
  return id;
}
const CLIENT = clientId();
const $ = (id) => document.getElementById(id);

function el(tag, attrs, text) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

// The stream needs the page's token (GET /session: only a page of this server's own origin can read it), so a
// page of another origin cannot open it and take control. A server that restarted (trackcal resume) has a new
// token: a stream it refuses is closed, and the page asks again.
async function connect() {
  try {
    const r = await fetch("/session", { credentials: "same-origin" });
    if (!r.ok) throw new Error("refused (" + r.status + ")");
    page.csrf = (await r.json()).csrf;
  } catch (e) {
    setTimeout(connect, RECONNECT_MS);
    return;
  }
  const src = new EventSource("/events?client=" + CLIENT + "&csrf=" + encodeURIComponent(page.csrf));
  src.addEventListener("snapshot", (m) => {
    const d = JSON.parse(m.data);
    page.view = d.view; page.points = d.points; page.plan = d.plan; page.live = d.live;
    heard();
    page.fresh.push(...page.points);
    page.plotDirty = true;
    schedule();
  });
  src.addEventListener("patch", (m) => {
    const d = JSON.parse(m.data);
    heard();
    if (!page.view) return;
    Object.assign(page.view, d.set);
    if (d.add.length) { page.points.push(...d.add); page.fresh.push(...d.add); page.plotDirty = true; }
    schedule();
  });
  src.addEventListener("live", (m) => { Object.assign(page.live, JSON.parse(m.data)); heard(); schedule(); });
  src.addEventListener("ping", heard);
  src.onerror = () => {
    page.connected = false; renderAll();
    if (src.readyState === EventSource.CLOSED) setTimeout(connect, RECONNECT_MS);
  };
}

// one render per frame however many messages arrive (a campaign sends bursts)
let scheduled = false;
function schedule() {
  if (scheduled) return;
  scheduled = true;
  requestAnimationFrame(() => {
    scheduled = false;
    renderAll();
    const now = performance.timeOrigin + performance.now();
    for (const p of page.fresh) if (!(p.id in window.trackcalSeen)) window.trackcalSeen[p.id] = now;
    page.fresh = [];
  });
}

function heard() { page.heard = Date.now(); page.connected = true; }

setInterval(() => {
  if (page.connected && Date.now() - page.heard > LOST_AFTER_MS) { page.connected = false; renderAll(); }
}, 500);

async function post(path, body) {
  const r = await fetch(path, { method: "POST", credentials: "same-origin",
    headers: { "Content-Type": "application/json", "X-Trackcal-CSRF": page.csrf },
    body: JSON.stringify({ client: CLIENT, ...body }) });
  let d = {};
  try { d = await r.json(); } catch (e) { d = { ok: false, why: "refused (" + r.status + ")" }; }
  return d;
}

$("answer").addEventListener("click", async () => {
  const p = page.view && page.view.prompt;
  if (!p || page.pending) return;
  page.pending = true; renderAll();
  const d = await post("/answer", { prompt: p.id });
  page.pending = false;
  if (d.ok) page.answered = p.id;  // until the session says it was answered, this one is not offered again
  $("answer-note").textContent = d.ok ? "sent" : "not taken: " + d.why;
  renderAll();
});
$("take").addEventListener("click", async () => { await post("/control", {}); });

// ------------------------------------------------------------------ rendering
function promptWords(p) {
  if (p.kind === "change_station") return ["Set up the tracker at station " + p.target, "Tracker set up: done"];
  if (p.kind === "move_reflector") return ["Put the reflector in nest " + p.target, "Reflector in " + p.target + ": done"];
  if (p.kind === "resume") return ["Leave the cell and close the door, then resume motion", "Resume motion"];
  return [p.text, "Done"];
}

function renderAll() {
  const v = page.view, live = page.live;
  // faded while trackcal is not running, unless the campaign is complete: its final state stays easy to read
  document.body.classList.toggle("lost", !page.connected && !(v && v.run.status === "success"));
  const status = $("status");
  let st = "connecting…", cls = "pill";
  if (v) {
    const run = v.run.status;
    if (!page.connected) {
      st = run === "success" ? "campaign complete (trackcal has ended)" : "campaign stopped: trackcal is not running";
      cls = run === "success" ? "pill ok" : "pill bad";
    } else if (live.stop && live.stop.exit_status !== "success" && run !== "running") {
      st = "stopped"; cls = "pill bad";
    } else if (run === "running") { st = "running"; cls = "pill ok"; }
    else if (run === "success") { st = "complete"; cls = "pill ok"; }
    else if (run === "stopped") { st = "stopped"; cls = "pill bad"; }
    else st = run;
  }
  status.textContent = st; status.className = cls;
  if (!v) return;
  $("cellname").textContent = page.plan ? "cell " + page.plan.cell : "";
  const replay = Boolean(page.plan && page.plan.replay), mine = live.controller === CLIENT && !replay;
  $("control").textContent = !page.connected ? "not connected" : replay ? "replay: the recording answers"
    : mine ? "you have control" : "watching (read-only)";
  $("control").className = !page.connected ? "pill" : mine ? "pill ok" : "pill warn";
  $("take").hidden = mine || replay || !page.connected;
  renderPrompt(v, live, mine);
  renderProgress(v);
  renderCell(v, live);
  renderWarnings(v);
  if (page.plotDirty) { renderPlot(); page.plotDirty = false; }
  renderFits(v.fits || []);
  const out = live.outcome;
  $("outcome-card").hidden = !out;
  if (out) {
    $("outcome").textContent = out.sentence;
    $("report").hidden = !out.report || !page.connected;
    if (out.report) $("report").href = out.report;
  }
}

function renderPrompt(v, live, mine) {
  const p = v.prompt, button = $("answer"), sentence = $("sentence");
  const drawing = $("drawing");
  drawing.replaceChildren();
  if (!page.connected && v.run.status !== "success") {
    sentence.textContent = "trackcal is not running: the campaign stopped" + (p ? " at “" + promptWords(p)[0] + "”" : "")
      + ". Resume it on the cell PC (trackcal resume).";
    button.textContent = "Nothing to answer";
    button.disabled = true;
    $("answer-note").textContent = "";
    drawCellMap(drawing, null, null);
    return;
  }
  if (!p) {
    const run = v.run.status;
    sentence.textContent = run === "success" ? "The campaign is complete."
      : run === "stopped" ? "The campaign stopped: " + v.run.reason
      : v.step.label ? "Robot working: " + v.step.label : "Waiting for trackcal…";
    button.textContent = "Nothing to answer";
    button.disabled = true;
    if (run !== "stopped") $("answer-note").textContent = "";
    drawCellMap(drawing, null, null);
    return;
  }
  const [words, label] = promptWords(p);
  sentence.textContent = p.text.startsWith("Resuming") ? "Resuming: " + words : words;
  button.textContent = label;
  const open = live.open === p.id;
  button.disabled = !(open && mine && page.connected && !page.pending && page.answered !== p.id);
  if (page.plan && page.plan.replay) $("answer-note").textContent = "A replay: the recording's answer is played back.";
  else if (!mine) $("answer-note").textContent = "Another page holds control: press “Take control” to answer here.";
  else if (!open) $("answer-note").textContent = "Waiting for the cell…";
  else if ($("answer-note").textContent.startsWith("Waiting") || $("answer-note").textContent.startsWith("Another"))
    $("answer-note").textContent = "";
  if (p.kind === "change_station") drawCellMap(drawing, p.target, null);
  else if (p.kind === "move_reflector") drawTool(drawing, p.target);
  else drawDoor(drawing, live.door_closed);
}

function fit(points, w, h, pad) {
  const xs = points.map((p) => p[0]), ys = points.map((p) => p[1]);
  const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const s = Math.min((w - 2 * pad) / Math.max(x1 - x0, 1e-9), (h - 2 * pad) / Math.max(y1 - y0, 1e-9));
  return (p) => [pad + (p[0] - x0) * s + ((w - 2 * pad) - (x1 - x0) * s) / 2,
                 h - pad - (p[1] - y0) * s - ((h - 2 * pad) - (y1 - y0) * s) / 2];
}

function drawCellMap(svg, target) {
  if (!page.plan) return;
  const st = Object.entries(page.plan.stations);
  const tf = fit([[0, 0], ...st.map(([, p]) => p)], 320, 200, 34);
  const [rx, ry] = tf([0, 0]);
  svg.append(el("rect", { x: rx - 14, y: ry - 14, width: 28, height: 28, fill: "#888" }),
             el("text", { x: rx, y: ry + 34, "text-anchor": "middle", "font-size": 16 }, "robot"));
  for (const [id, p] of st) {
    const [x, y] = tf(p), on = id === target;
    svg.append(el("polygon", { points: `${x},${y - 14} ${x - 13},${y + 10} ${x + 13},${y + 10}`,
                               fill: on ? "#c0582b" : "#bbb", stroke: on ? "#111" : "none", "stroke-width": 2 }),
               el("text", { x: x, y: y - 18, "text-anchor": "middle", "font-size": on ? 24 : 16,
                            "font-weight": on ? 700 : 400 }, id));
  }
}

function drawTool(svg, target) {
  if (!page.plan) return;
  // the two axes along which the points spread most (a tool's nests often share one coordinate)
  const pts = Object.entries(page.plan.points);
  const span = [0, 1, 2].map((a) => Math.max(...pts.map(([, p]) => p[a])) - Math.min(...pts.map(([, p]) => p[a])));
  const axes = [0, 1, 2].sort((a, b) => span[b] - span[a]).slice(0, 2).sort();
  const tf = fit(pts.map(([, p]) => [p[axes[0]], p[axes[1]]]), 320, 200, 44);
  svg.append(el("text", { x: 8, y: 194, "font-size": 14, fill: "#555" }, "measurement tool"));
  for (const [id, p] of pts) {
    const [x, y] = tf([p[axes[0]], p[axes[1]]]), on = id === target;
    svg.append(el("circle", { cx: x, cy: y, r: on ? 16 : 9, fill: on ? "#c0582b" : "#fff", stroke: "#111",
                              "stroke-width": 2 }),
               el("text", { x: x, y: y - 22, "text-anchor": "middle", "font-size": on ? 24 : 16,
                            "font-weight": on ? 700 : 400 }, id));
  }
}

function drawDoor(svg, closed) {
  const open = closed === false;
  svg.append(el("rect", { x: 110, y: 30, width: 100, height: 150, fill: "none", stroke: "#111", "stroke-width": 4 }),
             el("rect", { x: open ? 110 : 114, y: 34, width: open ? 30 : 92, height: 142,
                          fill: open ? "#f7d4d1" : "#d5efdc", stroke: "#111" }),
             el("text", { x: 160, y: 22, "text-anchor": "middle", "font-size": 20, "font-weight": 700 },
                closed === null || closed === undefined ? "door ?" : open ? "door OPEN" : "door closed"));
}

function fmtTime(s) {
  if (s === null || s === undefined) return "–";
  if (s < 90) return Math.round(s) + " s";
  if (s < 5400) return Math.round(s / 60) + " min";
  return (s / 3600).toFixed(1) + " h";
}

function renderProgress(v) {
  const pr = v.progress, step = v.step;
  $("stepline").textContent = step.index === null ? (v.run.status === "success" ? `all ${step.of} steps done` : "–")
    : `step ${step.index + 1} of ${step.of}`;
  const done = pr.measured + pr.skipped;
  $("bar-fill").style.width = (pr.planned ? (100 * done) / pr.planned : 0) + "%";
  $("counts").textContent = `${pr.measured} measured, ${pr.skipped} skipped of ${pr.planned}`;
  $("where").textContent = pr.pose ? `pose ${pr.pose}, point ${pr.point} from station ${pr.station}` : "";
  $("timeleft").textContent = "time left: about " + fmtTime(pr.time_left_s);
}

function tile(id, text, cls) { const t = $(id); t.textContent = text; t.className = cls; }

function renderCell(v, live) {
  const c = v.cell;
  const door = live.door_closed !== undefined && live.door_closed !== null ? live.door_closed : c.door_closed;
  tile("c-door", door === null || door === undefined ? "Door: ?" : door ? "Door closed" : "Door OPEN",
       door === null || door === undefined ? "" : door ? "ok" : "bad");
  const es = live.estop_ok;
  tile("c-estop", es === null || es === undefined ? "E-stop: ?" : es ? "E-stop released" : "E-STOP PRESSED",
       es === null || es === undefined ? "" : es ? "ok" : "bad");
  tile("c-robot", c.moving ? "Robot MOVING" : "Robot standing", c.moving ? "moving" : "ok");
  tile("c-tracker", c.locked === null ? "Tracker: ?" : c.locked ? "Tracker locked on" : "Tracker: no reflector",
       c.locked === null ? "" : c.locked ? "ok" : "bad");
  const m = c.meteo;
  tile("c-meteo", m ? `${m[0].toFixed(1)} °C · ${m[1].toFixed(0)} hPa · ${m[2].toFixed(0)} %` : "Meteo: ?", "");
}

function renderWarnings(v) {
  const ol = $("warnings");
  const shown = new Set(Array.from(ol.children, (li) => li.dataset.id));
  for (const w of v.warnings) {
    if (shown.has(String(w.id))) continue;  // each warning once
    const li = document.createElement("li");
    li.dataset.id = String(w.id);
    li.textContent = `t = ${Math.round(w.t)} s: ${w.message}`;
    ol.append(li);
    ol.scrollTop = ol.scrollHeight;  // the newest in view
  }
  $("no-warnings").hidden = v.warnings.length > 0;
}

function renderPlot() {
  const svg = $("plot");
  if (!page.plan) return;
  svg.replaceChildren();
  const stations = Object.keys(page.plan.stations);
  const w = 640 / Math.max(stations.length, 1);
  stations.forEach((sid, k) => {
    const color = COLORS[k % COLORS.length];
    const planned = page.plan.planned.filter((p) => p.station === sid && p.xyz);
    const measured = page.points.filter((p) => p.station === sid);
    svg.append(el("text", { x: k * w + 6, y: 26, "font-size": 28, "font-weight": 700, fill: color }, sid));
    if (!planned.length) return;
    const tf = fit([...planned, ...measured].map((p) => p.xyz), w, 170, 18);  // a stray measurement stays in view
    const g = el("g", { transform: `translate(${k * w},20)` });
    for (const p of planned) {
      const [x, y] = tf(p.xyz);
      g.append(el("circle", { cx: x, cy: y, r: 8, fill: "none", stroke: "#777", "stroke-width": 2 }));
    }
    for (const p of measured) { const [x, y] = tf(p.xyz); g.append(el("circle", { cx: x, cy: y, r: 5, fill: color })); }
    svg.append(g);
  });
  // deviation from the nominal expectation, one bar per measurement, in campaign order
  const devs = page.points.filter((p) => p.dev_mm !== null);
  const top = 218, hgt = 80, max = Math.max(1, ...devs.map((p) => p.dev_mm));
  svg.append(el("line", { x1: 0, y1: top + hgt, x2: 640, y2: top + hgt, stroke: "#999" }),
             el("text", { x: 636, y: top - 6, "font-size": 26, fill: "#555", "text-anchor": "end" },
                `bar height ${max.toFixed(1)} mm`));
  const bw = 640 / Math.max(page.plan.planned.length, 1);
  devs.forEach((p, i) => {
    const k = stations.indexOf(p.station), h = (hgt * p.dev_mm) / max;
    svg.append(el("rect", { x: i * bw, y: top + hgt - h, width: Math.max(bw - 1, 1), height: h,
                            fill: COLORS[(k < 0 ? 0 : k) % COLORS.length] }));
  });
}

// the residuals of each station block, from its station_fit document (engine/station_fit.py): one line of
// figures per station (text: wraps on a phone) and one bar per measurement, one scale for every station
function renderFits(fits) {
  const key = fits.map((f) => f.id).join(",") + "|" + (page.plan ? page.plan.cell : "");
  if (key === page.fitsShown || !page.plan) return;
  page.fitsShown = key;
  const stations = Object.keys(page.plan.stations);
  const list = $("fit-list"), svg = $("fits");
  list.replaceChildren();
  svg.replaceChildren();
  const norm = (r) => Math.hypot(...r.d_mm);
  const max = Math.max(1e-3, ...fits.flatMap((f) => f.residuals.map(norm)));
  const w = 640 / Math.max(stations.length, 1), top = 44, base = 150;
  stations.forEach((sid, k) => {
    const color = COLORS[k % COLORS.length], x0 = k * w;
    svg.append(el("text", { x: x0 + 6, y: 32, "font-size": 30, "font-weight": 700, fill: color }, sid),
               el("line", { x1: x0 + 4, y1: base, x2: x0 + w - 4, y2: base, stroke: "#999" }));
    const mine = fits.filter((f) => f.station === sid);
    if (!mine.length) {
      svg.append(el("text", { x: x0 + w / 2, y: 104, "font-size": 26, fill: "#777", "text-anchor": "middle" },
                    "after its block"));
      return;
    }
    const rows = mine.flatMap((f) => f.residuals), planned = mine.reduce((n, f) => n + f.planned, 0);
    const bw = (w - 12) / Math.max(planned, rows.length, 1);
    rows.forEach((r, i) => {
      const h = ((base - top) * norm(r)) / max;
      svg.append(el("rect", { x: x0 + 6 + i * bw, y: base - h, width: Math.max(bw - 1, 1), height: h, fill: color,
                              "data-station": sid, "data-step": r.step, "data-d": r.d_mm.join(",") }));
    });
    for (const f of mine) {
      const li = document.createElement("li");
      li.dataset.station = sid;
      li.dataset.block = String(f.block);
      li.textContent = f.residuals.length
        ? `${sid}: rms ${f.rms_mm.toFixed(3)} mm, max ${f.max_mm.toFixed(3)} mm (${f.measured} of ${f.planned} measured)`
        : `${sid}: not placed (${f.note})`;
      list.append(li);
    }
  });
  const now = performance.timeOrigin + performance.now();
  for (const f of fits) if (!(f.id in window.trackcalFitsSeen)) window.trackcalFitsSeen[f.id] = now;
  if (fits.length) svg.append(el("text", { x: 636, y: 180, "font-size": 26, fill: "#555", "text-anchor": "end" },
                `bar height ${max < 0.1 ? max.toFixed(3) : max.toFixed(2)} mm`));
}

connect();
