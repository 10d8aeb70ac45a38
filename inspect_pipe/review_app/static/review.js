// The review page: the register from /api/register, one edit at a time to /api/edit (queued, in
// order), keyboard-driven. window.review exposes the state for tests.
"use strict";
const R = window.review = { entries: [], sel: 0, pending: 0, saved: 0, errors: 0, lastError: null, state: null };
const $ = (id) => document.getElementById(id);
let queue = Promise.resolve();

function esc(s) { return String(s ?? "").replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" }[c])); }

function say(text, kind) { const m = $("msg"); m.textContent = text; m.className = kind || ""; }

function renderList() {
  const rows = R.entries.map((e, i) => `<tr data-i="${i}" id="row-${esc(e.id)}" class="${i === R.sel ? "sel" : ""}">` +
    `<td>${esc(e.id)}</td><td>${esc(e.class)}${e.detected_class ? ' <span class="small">(was ' + esc(e.detected_class) + ")</span>" : ""}</td>` +
    `<td class="${esc(e.status)}">${esc(e.status)}${e.redetected ? "" : ' <span class="small">not re-detected</span>'}</td>` +
    `<td class="num">${e.area_cm2}</td><td class="num">${e.confidence.toFixed(2)}</td><td class="small">${esc(e.note)}</td></tr>`);
  document.querySelector("#entries tbody").innerHTML = rows.join("");
}

function renderDetail() {
  const e = R.entries[R.sel];
  if (!e) { $("head").textContent = "the register has no entries"; return; }
  $("head").innerHTML = `<b>${esc(e.id)}</b> ${esc(e.class)}${e.detected_class ? " (detected as " + esc(e.detected_class) + ")" : ""}, ` +
    `<span class="${esc(e.status)}">${esc(e.status)}</span> &middot; ${e.area_cm2} cm&sup2;${e.length_cm != null ? ", " + e.length_cm + " cm long" : ""}` +
    ` &middot; u ${e.centroid_wall_m[0]} m, v ${e.centroid_wall_m[1]} m${e.location ? " &middot; " + esc(e.location) : ""}` +
    `${e.note ? '<br><span class="small">note: ' + esc(e.note) + "</span>" : ""}`;
  const bust = "?r=" + ((R.state && R.state.rendered && R.state.rendered.renders) || 0);
  $("crop").src = e.crop ? "/" + e.crop + bust : "";
  $("context").src = e.context ? "/" + e.context + bust : "";
  const ov = $("overlay"), box = $("box"), wh = R.state && R.state.mosaic_wh;
  if (R.state && R.state.overlay) {
    const src = "/" + R.state.overlay + bust;
    if (ov.getAttribute("src") !== src) ov.src = src;
  }
  const place = () => {
    if (!wh || !ov.clientWidth) { box.style.display = "none"; return; }
    const s = ov.clientWidth / wh[0], [x, y, w, h] = e.bbox_mosaic_xywh, pad = 4;
    Object.assign(box.style, { display: "block", left: (x * s - pad) + "px", top: (y * s - pad) + "px",
      width: (w * s + 2 * pad) + "px", height: (h * s + 2 * pad) + "px" });
  };
  if (ov.complete) place(); else ov.onload = place;
  const row = $("row-" + e.id);
  if (row) row.scrollIntoView({ block: "nearest" });
}

function renderHeader() {
  const s = R.state;
  $("reviewer").textContent = s.reviewer;
  $("run").textContent = s.run;
  $("saved").textContent = R.saved;
  $("audit").textContent = s.audit_lines;
  const r = s.rendered;
  $("rendered").textContent = r.error ? "not re-rendered: " + r.error
    : r.at ? `re-rendered ${r.at} (${r.seconds} s${r.pdf ? ", PDF" : ""})${s.dirty ? "; changes since" : ""}` : (s.dirty ? "changes not yet rendered" : "as the run wrote it");
}

function draw() { renderList(); renderDetail(); }

let editSeq = 0;  // edits asked for; a register fetched while one was asked for is stale

async function load(force) {
  const seq = editSeq;
  const res = await fetch("/api/register", { cache: "no-store" });
  if (res.status === 401) { location.reload(); return; }
  const state = await res.json();
  if (!force && (seq !== editSeq || R.pending)) return;
  R.state = state;
  const id = R.entries[R.sel] && R.entries[R.sel].id;
  R.entries = R.state.entries;
  const i = R.entries.findIndex((e) => e.id === id);
  R.sel = i >= 0 ? i : Math.min(R.sel, Math.max(0, R.entries.length - 1));
  renderHeader(); draw();
}

function edit(field, value) {
  const e = R.entries[R.sel];
  if (!e) return;
  const key = field;
  if (e[key] === value) { say(`${e.id}: already ${value || "without a note"}`, ""); return; }
  editSeq++;
  e[key] = value;  // shown at once; the server's answer replaces it (or a reload undoes it)
  draw();
  const body = JSON.stringify({ id: e.id, field: field, value: value });
  R.pending++;
  queue = queue.then(async () => {
    try {
      const res = await fetch("/api/edit", { method: "POST", headers: { "Content-Type": "application/json" }, body });
      const out = await res.json();
      if (!res.ok) { R.errors++; R.lastError = out.error; say(out.error, "err"); await load(true); return; }
      if (out.changed) R.saved++;
      const i = R.entries.findIndex((x) => x.id === out.entry.id);
      if (i >= 0 && R.pending === 1) R.entries[i] = out.entry;  // later edits queued: keep what they show
      R.state.audit_lines = out.audit_lines; R.state.dirty = R.state.dirty || out.changed;
      say(out.changed ? `${out.record.id}: ${out.record.field} ${JSON.stringify(out.record.before)} → ${JSON.stringify(out.record.after)} saved` : `${e.id}: no change`, "ok");
      renderHeader(); draw();
    } catch (err) {
      R.errors++; R.lastError = String(err); say("not saved: " + err, "err"); load(true);
    } finally { R.pending--; }
  });
}

function move(d) { if (!R.entries.length) return; R.sel = Math.max(0, Math.min(R.entries.length - 1, R.sel + d)); draw(); }

function openNote() {
  const e = R.entries[R.sel];
  if (!e) return;
  $("noteform").classList.add("open");
  const input = $("note");
  input.value = e.note || "";
  input.focus(); input.select();
}

function closeNote() { $("noteform").classList.remove("open"); $("note").blur(); }

$("noteform").addEventListener("submit", (ev) => { ev.preventDefault(); edit("note", $("note").value); closeNote(); });
$("note").addEventListener("keydown", (ev) => { if (ev.key === "Escape") { ev.preventDefault(); closeNote(); } });

async function renderNow() {
  say("re-rendering the report ...", "");
  await queue;
  const res = await fetch("/api/render", { method: "POST" });
  const out = await res.json();
  if (!res.ok || out.error) { say("report not re-rendered: " + (out.error || res.status), "err"); }
  else say(`report re-rendered in ${out.seconds} s${out.pdf ? " (HTML and PDF)" : " (HTML)"}`, "ok");
  await load(true);
}
R.renderNow = renderNow;
R.idle = () => queue;

document.addEventListener("keydown", (ev) => {
  if (ev.target && ev.target.id === "note") return;
  if (ev.ctrlKey || ev.metaKey || ev.altKey) return;
  const e = R.entries[R.sel];
  const keys = {
    j: () => move(1), ArrowDown: () => move(1), k: () => move(-1), ArrowUp: () => move(-1),
    c: () => edit("status", "confirmed"), r: () => edit("status", "rejected"), s: () => edit("status", "suggested"),
    t: () => e && edit("class", e.class === "crack" ? "corrosion" : "crack"),
    n: () => openNote(), p: () => renderNow(),
  };
  const f = keys[ev.key];
  if (f) { ev.preventDefault(); f(); }
});
document.querySelector("#entries tbody").addEventListener("click", (ev) => {
  const tr = ev.target.closest("tr"); if (tr) { R.sel = Number(tr.dataset.i); draw(); }
});
window.addEventListener("resize", renderDetail);
setInterval(() => { if (!R.pending) load(); }, 5000);
load();
