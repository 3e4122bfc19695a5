// handeye-jax tablet page. Units: tablet px are CSS px measured from the page's top-left
// corner (eq. 9: one tablet px = 25.4 / ppi * scale mm). Progress lives in localStorage until
// the server acknowledges it, so a reload or a dropped connection loses nothing.
"use strict";

const STORE = "handeye-jax.tablet/1:";
const RETRY_MS = 3000;
const $ = (id) => document.getElementById(id);

const app = {
  session: load("session", null), // last session seen, so a reload works with the server down
  run: load("run", null),         // the run in progress
  outbox: load("outbox", []),     // finished runs the server has not acknowledged yet
  parked: load("parked", []),     // runs kept for a dataset the server does not serve now
  marks: load("marks", true),     // draw the faint rings and numbers beside the dots
  pictures: false,                // showing only the dots, for the camera's pictures
  dotPx: [1, 2, 3].includes(load("dot_px", 1)) ? load("dot_px", 1) : 1, // dot side, tablet px
  stale: false,                   // app.run belongs to another dataset: the operator decides
  summary: null,
  locked: false,                  // the server refused this page's secret (it was restarted)
  flushing: false,
  retryTimer: null,
};

function load(key, fallback) {
  try {
    const text = localStorage.getItem(STORE + key);
    return text === null ? fallback : JSON.parse(text);
  } catch (e) {
    return fallback;
  }
}

function store(key, value) {
  try {
    if (value === null) localStorage.removeItem(STORE + key);
    else localStorage.setItem(STORE + key, JSON.stringify(value));
    app.storageFailed = false;
  } catch (e) {
    app.storageFailed = true; // private mode or full: the page works, but a reload would lose
  }
}

function newId() {
  // crypto.randomUUID needs a secure context; a tablet on the LAN loads the page over http.
  return Date.now().toString(36) + "-" + Math.random().toString(36).slice(2, 12);
}

const round3 = (v) => Math.round(v * 1000) / 1000;
const fmt = (v, d = 2) => (Number.isFinite(v) ? v.toFixed(d) : "–");

function mmPerPx() {
  return app.session ? app.session.tablet.mm_per_px : NaN;
}

// -- which dataset a run belongs to ---------------------------------------------------------

// The fingerprint of the landmarks a run or outbox item was measured on, as the current
// session names them: the dataset's key, the targets file's key, or undefined (a grid, or no
// session yet), in which case there is nothing to compare.
function currentKey(what) {
  const s = app.session;
  if (!s) return undefined;
  if (what.kind === "calibration" || what.source === "dataset") return s.dataset ? s.dataset.key : null;
  if (what.source === "file") return s.targets_file ? s.targets_file.key : null;
  return undefined;
}

function belongsElsewhere(what) {
  const key = currentKey(what);
  return !!what.key && key !== undefined && key !== what.key;
}

// After a session arrives: a stored run of another dataset is not resumed silently, and a
// run kept for this session's dataset comes back.
function checkRunKeys() {
  app.stale = !!app.run && belongsElsewhere(app.run);
  if (app.run) return;
  const i = app.parked.findIndex((r) => r.key && currentKey(r) === r.key);
  if (i < 0) return;
  app.run = app.parked[i];
  app.parked.splice(i, 1);
  store("run", app.run); // first into the run, then out of the parked list: never in neither
  store("parked", app.parked);
  showOutbox(`resumed the ${app.run.kind} run kept for ${app.run.name || "these targets"}`, "ok");
}

function describeRun(run) {
  const done = run.touches.filter(Boolean).length;
  const what = run.kind === "calibration" ? `calibration of ${run.name}` : `${run.label} trial`;
  return `${what}, ${done} of ${run.targets.length} touched, started ${run.started}`;
}

function discardStale() {
  if (!confirm("Discard this run? Its touches are lost.")) return;
  app.run = null;
  app.stale = false;
  save();
}

function parkStale() {
  app.parked.push(app.run);
  store("parked", app.parked); // first into the parked list, then out of the run
  app.run = null;
  app.stale = false;
  save();
  showOutbox("run kept in this browser: it resumes when the server serves its dataset again", "ok");
}

// -- drawing --------------------------------------------------------------------------------

function targetsOnScreen() {
  if (app.run && !app.stale) return app.run.targets;
  const ds = app.session && app.session.dataset;
  return ds ? ds.tablet_px : [];
}

function draw() {
  const canvas = $("board");
  const dpr = window.devicePixelRatio || 1;
  const w = window.innerWidth, h = window.innerHeight;
  canvas.style.width = w + "px";
  canvas.style.height = h + "px";
  canvas.width = Math.round(w * dpr);
  canvas.height = Math.round(h * dpr);
  const ctx = canvas.getContext("2d");
  ctx.setTransform(1, 0, 0, 1, 0, 0); // draw in device px, so the dots stay crisp
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  const targets = targetsOnScreen();
  const run = app.stale || app.pictures ? null : app.run;
  const marks = app.marks && !app.pictures; // a picture shows the dots alone
  ctx.font = `${Math.round(12 * dpr)}px system-ui, sans-serif`;
  targets.forEach(([x, y], m) => {
    const cx = x * dpr, cy = y * dpr;
    const current = run && run.current === m;
    ctx.lineWidth = Math.max(1, dpr);
    if (marks) { // the faint ring and the number; off, only the one-pixel dot is left
      ctx.strokeStyle = current ? "#2a6fdb" : "#e0e0e0";
      ctx.beginPath();
      ctx.arc(cx, cy, (current ? 22 : 12) * dpr, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.fillStyle = current ? "#2a6fdb" : "#9a9a9a";
      const off = (current ? 18 : 10) * dpr;
      ctx.fillText(String(m), cx + off, cy - off);
    }
    const t = run && run.touches[m];
    if (t) {
      ctx.strokeStyle = "#e0301e"; // where the pen landed
      const px = t.touch_px[0] * dpr, py = t.touch_px[1] * dpr, r = 4 * dpr;
      ctx.beginPath();
      ctx.moveTo(px - r, py); ctx.lineTo(px + r, py);
      ctx.moveTo(px, py - r); ctx.lineTo(px, py + r);
      ctx.stroke();
    }
  });
  // The landmark: a square of dotPx tablet px (one, as the paper's, unless chosen), black,
  // centred on (x, y); drawn last so nothing covers it.
  const side = Math.max(1, Math.round(app.dotPx * dpr));
  ctx.fillStyle = "#000";
  for (const [x, y] of targets) {
    ctx.fillRect(Math.round(x * dpr - side / 2), Math.round(y * dpr - side / 2), side, side);
  }
  placePanel(targets);
}

function placePanel(targets) {
  // Put the panel in the corner where it covers no target (or the fewest), ring included.
  const panel = $("panel");
  const gap = 8, ring = 24;
  const w = panel.offsetWidth, h = panel.offsetHeight;
  const W = window.innerWidth, H = window.innerHeight;
  const corners = [["bottom", "right"], ["bottom", "left"], ["top", "right"], ["top", "left"]];
  let best = corners[0], fewest = Infinity;
  for (const [v, s] of corners) {
    const x0 = s === "left" ? gap : W - gap - w, y0 = v === "top" ? gap : H - gap - h;
    const n = targets.filter(([x, y]) =>
      x > x0 - ring && x < x0 + w + ring && y > y0 - ring && y < y0 + h + ring).length;
    if (n < fewest) { fewest = n; best = [v, s]; }
  }
  panel.classList.remove("top", "bottom", "left", "right");
  panel.classList.add(...best);
}

// -- the panel ------------------------------------------------------------------------------

function showWarnings() {
  const notes = [];
  const s = app.session;
  const dpr = window.devicePixelRatio || 1;
  if (s && Math.abs(dpr - s.tablet.scale) > 0.005) {
    notes.push(
      `Display scale mismatch: this screen's devicePixelRatio is ${dpr} but the tablet's ` +
      `scale is ${s.tablet.scale}: one px here is not the dataset's ${fmt(s.tablet.mm_per_px, 4)} mm, ` +
      `so the landmarks are drawn at other physical places and every mm figure is wrong. ` +
      `Set the display scale to ${s.tablet.scale * 100}% and the ` +
      `browser zoom to 100%, or correct [tablet] scale in the dataset.`);
  }
  if (app.locked) {
    notes.push("The server does not know this page's secret (was it restarted?): open the URL " +
      "it printed, or scan its QR code. Runs kept in this browser are not lost.");
  } else if (!s) notes.push("No contact with the server yet: nothing to draw.");
  if (app.storageFailed) notes.push("This browser refuses to store progress: a reload loses it.");
  const W = window.innerWidth, H = window.innerHeight;
  const off = targetsOnScreen().findIndex(([x, y]) => x < 0 || y < 0 || x >= W || y >= H);
  if (off >= 0) {
    const [x, y] = targetsOnScreen()[off];
    notes.push(`Point ${off} at (${x}, ${y}) px lies outside this ${W} × ${H} px page: ` +
      "use full screen, or draw the landmarks inside the page.");
  }
  if (s && s.result && s.result.note) notes.push(`Result: ${s.result.note}.`);
  const box2 = $("stale");
  box2.hidden = !app.stale;
  if (app.stale) {
    const ds = s && s.dataset;
    $("stale-text").textContent =
      `The run stored in this browser (${describeRun(app.run)}) was measured on other ` +
      `landmarks than the server's now (${ds ? ds.name + ", " + ds.file : "no dataset"}): ` +
      "the server was restarted with another dataset. It is not resumed here. Discard it, or " +
      "keep it for its own dataset (it resumes when the server serves that dataset again).";
  }
  const box = $("warning");
  box.hidden = notes.length === 0;
  box.textContent = notes.join(" ");
  box.dataset.mismatch = s && Math.abs(dpr - s.tablet.scale) > 0.005 ? "1" : "0";
  if (notes.length || app.stale) $("panel").classList.remove("folded");
}

function showInfo() {
  const s = app.session;
  if (!s) return;
  const ds = s.dataset;
  const mm = s.tablet.mm_per_px;
  $("tablet-info").textContent =
    `${ds ? ds.name + ": " + ds.tablet_px.length + " landmarks; " : ""}` +
    `${s.tablet.ppi} ppi, scale ${s.tablet.scale}: 1 px = ${mm.toFixed(4)} mm` +
    (s.result ? `; evaluating ${s.result.model} seed ${s.result.seed} (${s.result.file})` : "");
  const rulerMm = 20;
  $("ruler").style.width = `${rulerMm / mm}px`;
  $("ruler-label").textContent = `${rulerMm} mm: check with a ruler`;
  $("start-calibration").disabled = !ds;
  const src = $("target-source");
  src.querySelector('option[value="dataset"]').disabled = !ds;
  src.querySelector('option[value="file"]').disabled = !s.targets_file;
  if (src.selectedOptions[0] && src.selectedOptions[0].disabled) src.value = "grid";
  $("grid-inputs").hidden = src.value !== "grid";
}

// The pictures the dataset holds (its captures): the hand pose of each and what it sees.
function showCaptures() {
  const ds = app.session && app.session.dataset;
  $("start-pictures").disabled = !ds;
  const caps = (ds && ds.captures) || [];
  const items = caps.map((c) => {
    const li = document.createElement("li");
    const [x, y, z] = c.hand_position_mm.map((v) => fmt(v, 1));
    li.textContent = `hand at (${x}, ${y}, ${z}) mm, ${fmt(c.hand_angle_deg, 1)} deg: ` +
      `${c.landmarks.length} of ${ds.tablet_px.length} landmarks` +
      (c.landmarks.length ? "" : ": to take");
    return li;
  });
  if (ds && ds.version === 1) {
    const li = document.createElement("li");
    li.textContent = "a version-1 dataset holds one picture: handeye-jax convert it for more";
    li.className = "note";
    items.push(li);
  }
  $("captures").replaceChildren(...items);
}

function setPictures(on) {
  app.pictures = on;
  $("panel").hidden = on;
  render();
}

function showRun() {
  const run = app.stale ? null : app.run;
  $("menu").hidden = !!app.run;
  $("run").hidden = !run;
  $("marks").checked = app.marks;
  $("dot-px").value = String(app.dotPx);
  if (!run) return;
  const n = run.targets.length;
  const done = run.touches.filter(Boolean).length;
  const what = run.kind === "calibration" ? "landmark" : "target";
  $("prompt").textContent = run.current >= 0
    ? `${run.kind}: touch ${what} ${run.current} (${done} of ${n} done)`
    : `${run.kind}: all ${n} touched. Retake any, or send.`;
  const mm = mmPerPx();
  const rows = run.targets.map(([x, y], m) => {
    const t = run.touches[m];
    const tr = document.createElement("tr");
    tr.dataset.m = m;
    if (run.current === m) tr.className = "current";
    let cells = [m, "", "", "", "", ""];
    if (t) {
      const dx = t.touch_px[0] - x, dy = t.touch_px[1] - y, e = Math.hypot(dx, dy);
      cells = [m, fmt(dx), fmt(dy), fmt(e), fmt(e * mm), t.pointer_type];
    }
    for (const c of cells) {
      const td = document.createElement("td");
      td.textContent = c;
      tr.appendChild(td);
    }
    const td = document.createElement("td");
    if (t) {
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = "retake";
      b.className = "retake";
      b.onclick = () => { run.current = m; save(); };
      td.appendChild(b);
    }
    tr.appendChild(td);
    return tr;
  });
  $("touches").tBodies[0].replaceChildren(...rows);
  const dists = run.touches.map((t, m) => t &&
    Math.hypot(t.touch_px[0] - run.targets[m][0], t.touch_px[1] - run.targets[m][1]))
    .filter((d) => d !== null);
  const mean = dists.reduce((a, b) => a + b, 0) / Math.max(1, dists.length);
  const max = Math.max(0, ...dists);
  $("run-summary").textContent = dists.length
    ? `mean ${fmt(mean)} px = ${fmt(mean * mm)} mm; max ${fmt(max)} px = ${fmt(max * mm)} mm`
    : "";
  $("send").hidden = run.current >= 0;
}

function showOutbox(message, kind) {
  if (message !== undefined) {
    $("status").textContent = message;
    $("status").className = kind || "";
  }
  const items = app.outbox.map((item) => {
    const li = document.createElement("li");
    const elsewhere = !item.rejected && belongsElsewhere(item);
    li.textContent = `${item.what}: ` +
      (item.rejected ? `refused (${item.rejected.status}): ${item.rejected.error}`
        : elsewhere ? "measured on another dataset's landmarks: kept until the server serves it again"
          : "waiting for the server");
    if (item.rejected || elsewhere) {
      li.className = item.rejected ? "rejected" : "held";
      const b = document.createElement("button");
      b.type = "button";
      b.textContent = "discard";
      b.onclick = () => {
        if (elsewhere && !confirm("Discard these touches? They are lost.")) return;
        app.outbox = app.outbox.filter((o) => o !== item);
        store("outbox", app.outbox);
        showOutbox();
      };
      li.appendChild(b);
    }
    return li;
  });
  $("outbox").replaceChildren(...items);
}

function showSummary(summary) {
  if (summary) app.summary = summary;
  const blocks = app.summary || [];
  $("results").hidden = blocks.length === 0 || !!app.run; // a short panel during a run
  const table = $("summary");
  table.replaceChildren();
  for (const b of blocks) {
    const head = table.insertRow();
    const th = document.createElement("th");
    th.colSpan = b.trials.length + 2;
    th.textContent = `${b.label}: touching error`;
    head.appendChild(th);
    const rows = [["trial", ...b.trials.map((t) => t.trial), "average"]];
    for (const u of ["px", "mm"]) {
      rows.push([`in ${u}`, ...b.trials.map((t) => fmt(t[`mean_${u}`])), fmt(b.average[`mean_${u}`])]);
    }
    for (const u of ["px", "mm"]) {
      rows.push([`max ${u}`, ...b.trials.map((t) => fmt(t[`max_${u}`])), fmt(b.average[`max_${u}`])]);
    }
    for (const r of rows) {
      const tr = table.insertRow();
      tr.className = "summary-row";
      for (const c of r) tr.insertCell().textContent = c;
    }
  }
}

function render() {
  showWarnings();
  showInfo();
  showCaptures();
  showRun();
  showOutbox();
  showSummary();
  draw();
}

function save() {
  store("run", app.run);
  render();
}

// -- runs -----------------------------------------------------------------------------------

function startRun(kind, targets, extra) {
  app.run = {
    kind, id: newId(), targets, touches: targets.map(() => null), current: 0,
    penSeen: false, started: new Date().toISOString(), ...extra,
  };
  save();
}

async function startEvaluation() {
  const s = app.session;
  const source = $("target-source").value;
  let targets;
  if (source === "dataset") targets = s.dataset.tablet_px;
  else if (source === "file") targets = s.targets_file.tablet_px;
  else {
    const q = new URLSearchParams();
    for (const k of ["cols", "rows", "left", "top", "right", "bottom"]) q.set(k, $(`grid-${k}`).value);
    try {
      const r = await fetch(`api/grid?${q}`);
      const doc = await r.json();
      if (!r.ok) return showOutbox(`grid refused: ${doc.field}: ${doc.error}`, "error");
      targets = doc.tablet_px;
    } catch (e) {
      return showOutbox("cannot reach the server to make the grid", "error");
    }
  }
  const key = source === "dataset" ? s.dataset.key : source === "file" ? s.targets_file.key : null;
  startRun("evaluation", targets, {
    source, key, name: `${source} targets`, label: $("trial-label").value.trim() || "trial",
  });
}

function onPointerDown(ev) {
  if (app.pictures) { // the picture is taken: any contact brings the panel back
    ev.preventDefault();
    setPictures(false);
    return;
  }
  const run = app.run;
  if (!run || app.stale || run.current < 0) return;
  const type = ev.pointerType;
  if (!["pen", "touch", "mouse"].includes(type)) return;
  if (type === "pen") run.penSeen = true;
  else if (run.penSeen) {
    // pen preferred: once a pen has touched, a palm or finger on the glass is not a touch.
    showOutbox(`ignored a ${type} contact: this run uses the pen`);
    return;
  }
  ev.preventDefault();
  run.touches[run.current] = { touch_px: [round3(ev.clientX), round3(ev.clientY)], pointer_type: type };
  const next = run.touches.findIndex((t) => t === null);
  run.current = next; // -1 when every target has a touch
  save();
}

function finishRun() {
  const run = app.run;
  if (!run || app.stale || run.current >= 0) return;
  let item;
  if (run.kind === "calibration") {
    item = {
      id: run.id, url: "api/calibration", what: `calibration of ${run.name}`,
      kind: run.kind, key: run.key,
      body: {
        run_id: run.id,
        ...(run.key ? { key: run.key } : {}), // the server refuses touches of other landmarks
        touches: run.targets.map(([x, y], m) => ({
          m, tablet_px: [x, y], pointer_type: run.touches[m].pointer_type,
          touch_error_px: [round3(run.touches[m].touch_px[0] - x), round3(run.touches[m].touch_px[1] - y)],
        })),
      },
    };
  } else {
    item = {
      id: run.id, url: "api/evaluation", what: `${run.label} trial (${run.source} targets)`,
      kind: run.kind, source: run.source, key: run.key,
      body: {
        run_id: run.id, label: run.label, targets: run.source,
        touches: run.targets.map((xy, m) => ({
          m, target_px: xy, touch_px: run.touches[m].touch_px,
          pointer_type: run.touches[m].pointer_type,
        })),
      },
    };
  }
  app.outbox.push(item);
  store("outbox", app.outbox); // first into the outbox, then out of the run: never in neither
  app.run = null;
  save();
  showOutbox(`sending ${item.what}…`); // not "ok": the last run's "saved" must not linger
  flush();
}

async function flush() {
  if (app.flushing) {
    app.flushAgain = true; // an item queued while a pass is under way goes in the next pass
    return;
  }
  app.flushing = true;
  clearTimeout(app.retryTimer);
  let retry = false;
  for (const item of [...app.outbox]) {
    if (item.rejected || belongsElsewhere(item)) continue;
    let r, doc;
    try {
      r = await fetch(item.url, {
        method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify(item.body),
      });
      doc = await r.json();
    } catch (e) {
      retry = true;
      showOutbox(`server unreachable: ${item.what} is kept in this browser; retrying`, "error");
      break;
    }
    if (r.status === 403) { // no secret, or not the server's: kept until the page has it
      app.locked = true;
      showOutbox(`not sent: ${doc.error}`, "error");
      break;
    }
    app.locked = false;
    if (r.ok) {
      app.outbox = app.outbox.filter((o) => o.id !== item.id);
      store("outbox", app.outbox);
      if (item.url.endsWith("calibration")) {
        const types = Object.entries(doc.pointer_types).map(([k, v]) => `${v} ${k}`).join(", ");
        showOutbox(`saved: touch_error_px (${types}; mean ${fmt(doc.mean_px)} px = ${fmt(doc.mean_mm)} mm) ` +
          `written to ${doc.saved}` + (doc.backup ? `; previous file kept as ${doc.backup}` : ""), "ok");
        refreshSession();
      } else {
        showOutbox(`saved: ${doc.label} trial ${doc.trial}: mean ${fmt(doc.mean_px)} px = ` +
          `${fmt(doc.mean_mm)} mm, max ${fmt(doc.max_px)} px = ${fmt(doc.max_mm)} mm, in ${doc.saved}`, "ok");
        showSummary(doc.summary);
      }
    } else if (r.status >= 400 && r.status < 500 && r.status !== 429) { // 429: saved too often, retry
      item.rejected = { status: r.status, error: (doc.field ? doc.field + ": " : "") + doc.error };
      store("outbox", app.outbox);
      showOutbox(`refused by the server: ${item.rejected.error}`, "error");
    } else {
      retry = true;
      showOutbox(`server error ${r.status}: ${doc.error}; kept in this browser; retrying`, "error");
      break;
    }
  }
  app.flushing = false;
  showOutbox();
  showWarnings(); // a refused secret shows there
  if (retry) app.retryTimer = setTimeout(flush, RETRY_MS);
  else if (app.flushAgain) {
    app.flushAgain = false;
    flush();
  }
}

async function refreshSession() {
  try {
    const r = await fetch("api/session", { cache: "no-store" });
    const doc = await r.json();
    if (r.status === 403) { // retrying cannot help: the operator must open the printed URL
      app.locked = true;
      showOutbox(`cannot load the session: ${doc.error}`, "error");
      render();
      return;
    }
    if (!r.ok) throw new Error(doc.error);
    app.locked = false;
    app.session = doc;
    store("session", doc);
    app.summary = doc.trials.summary;
    checkRunKeys();
  } catch (e) {
    showOutbox(`cannot load the session (${e.message}); using the last one seen`, "error");
    setTimeout(refreshSession, RETRY_MS);
  }
  render();
}

function init() {
  $("board").addEventListener("pointerdown", onPointerDown);
  $("board").addEventListener("contextmenu", (ev) => ev.preventDefault());
  $("fold").onclick = () => $("panel").classList.toggle("folded");
  $("start-calibration").onclick = () => {
    const ds = app.session.dataset;
    startRun("calibration", ds.tablet_px, { key: ds.key, name: ds.name });
  };
  $("start-evaluation").onclick = startEvaluation;
  $("start-pictures").onclick = () => setPictures(true);
  window.addEventListener("keydown", (ev) => { if (ev.key === "Escape" && app.pictures) setPictures(false); });
  $("target-source").onchange = render;
  $("send").onclick = finishRun;
  $("abandon").onclick = () => {
    if (confirm("Abandon this run? Its touches are lost.")) { app.run = null; save(); }
  };
  $("stale-discard").onclick = discardStale;
  $("stale-keep").onclick = parkStale;
  $("marks").onchange = () => {
    app.marks = $("marks").checked;
    store("marks", app.marks);
    render();
  };
  $("dot-px").onchange = () => {
    app.dotPx = Number($("dot-px").value);
    store("dot_px", app.dotPx);
    render();
  };
  window.addEventListener("resize", render);
  window.addEventListener("online", flush);
  checkRunKeys(); // against the last session seen, until the server answers
  render();
  refreshSession().then(flush);
}

init();
