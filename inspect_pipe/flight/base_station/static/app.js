// Base station page: live state over a WebSocket, commands from the keyboard or a gamepad.
"use strict";
const MODES = {0: "0 bottom flow", 1: "1 bottom + front flow", 2: "2 TeraRanger + front flow",
               3: "3 front flow only", "-1": "-1 alarm: TeraRanger only", "-2": "-2 alarm: no sensors"};
const $ = (id) => document.getElementById(id);
// No token here: the session cookie (HttpOnly, set by POST /login) goes with the WebSocket handshake.
const wsUrl = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + "/ws";
let ws = null, role = "watch", limits = {vx: 1, vy: 1, vz: 0.5, yaw_rate: 0.8};
const keys = new Set();
let stateCount = 0, rateT0 = performance.now();
window.basestation = {states: 0, lastState: null, errors: [], mosaicVersion: 0};  // for tests and the curious

function fmt(v, unit, nd = 2) { return v === null || v === undefined ? "n/a" : v.toFixed(nd) + " " + unit; }
function cmdText(c) { return c ? `${c.vx.toFixed(2)} / ${c.vy.toFixed(2)} / ${c.vz.toFixed(2)} m/s, ${c.yaw_rate.toFixed(2)} rad/s` : "-"; }

function send(msg) { if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg)); }
function button(name) { send({type: "button", button: name}); }

function stick() {
  const k = (a, b) => (keys.has(a) ? 1 : 0) - (keys.has(b) ? 1 : 0);
  let s = {vx: 0.5 * k("w", "s"), vy: 0.5 * k("a", "d"), vz: 0.3 * k("r", "f"), yaw_rate: 0.5 * k("q", "e")};
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  for (const p of pads) {
    if (!p) continue;
    const dz = (v) => (Math.abs(v) < 0.1 ? 0 : v);
    if (p.axes.length >= 4) {
      s = {vx: s.vx || -dz(p.axes[1]) * limits.vx, vy: s.vy || -dz(p.axes[0]) * limits.vy,
           vz: s.vz || -dz(p.axes[3]) * limits.vz, yaw_rate: s.yaw_rate || -dz(p.axes[2]) * limits.yaw_rate};
    }
    padButtons(p);
    break;
  }
  return s;
}

const padPrev = {};
function padButtons(p) {
  const map = {0: "takeoff", 1: "land", 2: "go_ahead"};
  p.buttons.forEach((b, i) => {
    if (b.pressed && !padPrev[i]) {
      if (map[i]) button(map[i]);
      if (i === 3) button(window.basestation.lastState && window.basestation.lastState.inspection_mode ? "inspection_mode_off" : "inspection_mode_on");
    }
    padPrev[i] = b.pressed;
  });
}

// The stick goes out at a steady 20 Hz whatever the keys do: onboard, silence is link loss.
setInterval(() => { if (role === "control") send({type: "stick", ...stick(), t_ms: Date.now()}); }, 50);

const KEYMAP = {arrowup: "w", arrowdown: "s", arrowleft: "a", arrowright: "d"};
document.addEventListener("keydown", (e) => {
  const k = KEYMAP[e.key.toLowerCase()] || e.key.toLowerCase();
  if ("wsadrfqe".includes(k) && k.length === 1) {
    if (!keys.has(k)) { keys.add(k); if (role === "control") send({type: "stick", ...stick(), t_ms: Date.now()}); }
    e.preventDefault();
    return;
  }
  if (e.repeat) return;
  const b = {t: "takeoff", l: "land", i: "inspection_mode_on", o: "inspection_mode_off", g: "go_ahead"}[k];
  if (b) { button(b); e.preventDefault(); }
});
document.addEventListener("keyup", (e) => {
  const k = KEYMAP[e.key.toLowerCase()] || e.key.toLowerCase();
  if (keys.delete(k) && role === "control") send({type: "stick", ...stick(), t_ms: Date.now()});
});
window.addEventListener("blur", () => keys.clear());
document.querySelectorAll("button[data-button]").forEach((b) => b.addEventListener("click", () => button(b.dataset.button)));
$("btn-control").addEventListener("click", () => send({type: role === "control" ? "release_control" : "take_control"}));

function setRole(r) {
  role = r;
  $("role").textContent = r === "control" ? "in control" : "watching";
  $("btn-control").textContent = r === "control" ? "Release control" : "Take control";
  document.querySelectorAll("button[data-button]").forEach((b) => (b.disabled = r !== "control"));
}

function show(s) {
  window.basestation.states += 1;
  window.basestation.lastState = s;
  stateCount += 1;
  $("fsm").textContent = s.fsm || "-";
  $("mode").textContent = MODES[String(s.est_mode)] || String(s.est_mode);
  $("height").textContent = fmt(s.height, "m");
  $("speed").textContent = `${fmt(s.vx, "")}/ ${fmt(s.vy, "")}/ ${fmt(s.vz, "m/s")}`;
  const d = s.dist || {};
  $("front").textContent = fmt(d.front, "m");
  $("sides").textContent = `${fmt(d.left, "m")} / ${fmt(d.right, "m")}`;
  $("floor").textContent = fmt(d.down, "m");
  $("battery").textContent = fmt(s.battery_percent, "%", 0);
  $("inspection").textContent = s.inspection_mode ? "on" : "off";
  $("user").textContent = cmdText(s.user_cmd);
  $("cmd").textContent = cmdText(s.cmd);
  $("behaviors").textContent = (s.behaviors || []).join(", ") || "none";
  $("link").textContent = s.link_ok ? "ok" : "lost";
  $("link").className = s.link_ok ? "ok" : "bad";
  const v = s.vehicle || {};
  $("vlink").textContent = s.vehicle_ok ? (v.autopilot ? `${v.autopilot}, ${v.landed_state}, ${v.messages_per_s} msg/s` : "embedded simulator") : "no heartbeat";
  $("time").textContent = fmt(s.t, "s", 1);
  $("feedback").innerHTML = "";
  for (const f of s.feedback || []) { const div = document.createElement("div"); div.textContent = f; $("feedback").appendChild(div); }
  $("frames-count").textContent = String(s.frames_captured || 0);
  if (s.latency_ms && s.latency_ms.p99 !== null) $("latency").textContent = s.latency_ms.p99.toFixed(0);
  if (s.mosaic) {
    if (s.mosaic.frames || s.inspection_mode) $("mosaic-line").textContent = s.mosaic.line;
    $("mosaic-problem").textContent = s.mosaic.problem || "";
  }
}

setInterval(() => {
  const now = performance.now();
  $("rate").textContent = (stateCount * 1000 / (now - rateT0)).toFixed(0);
  window.basestation.rateHz = stateCount * 1000 / (now - rateT0);
  stateCount = 0; rateT0 = now;
}, 1000);

function connect() {
  ws = new WebSocket(wsUrl);
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data);
    if (m.type === "state") show(m);
    else if (m.type === "image") $("camera").src = "data:image/jpeg;base64," + m.jpeg;
    else if (m.type === "mosaic") {
      $("mosaic").src = "data:image/jpeg;base64," + m.mosaic_jpeg;
      $("coverage").src = "data:image/png;base64," + m.coverage_png;
      window.basestation.mosaicVersion = m.version;
    }
    else if (m.type === "frame") {
      const img = document.createElement("img");
      img.src = "data:image/jpeg;base64," + m.jpeg; img.title = "frame " + m.index;
      $("frames").prepend(img);
      while ($("frames").children.length > 12) $("frames").lastChild.remove();
    } else if (m.type === "hello") {
      $("vehicle").textContent = m.vehicle; limits = m.limits || limits; setRole(m.role);
      if (!m.mosaic) $("mosaic-line").textContent = "no live mosaic: no camera stream from this vehicle (the capture service records the sweep)";
    }
    else if (m.type === "role") setRole(m.role);
    else if (m.type === "error") { $("error").textContent = m.message; window.basestation.errors.push(m.message); }
  };
  let opened = false;
  ws.onopen = () => { opened = true; };
  ws.onclose = (ev) => {
    setRole("watch");
    if (ev.code === 1008 || !opened) {  // refused (logged out, session gone after a restart): the page shows the login form
      $("role").textContent = "not logged in: reloading";
      setTimeout(() => fetch("/", {method: "HEAD", cache: "no-store"}).then((r) => { if (r.status === 401) location.reload(); else setTimeout(connect, 1000); },
                                                                     () => setTimeout(connect, 1000)), 1000);
      return;
    }
    $("role").textContent = "disconnected: retrying"; setTimeout(connect, 1000);
  };
}
connect();
