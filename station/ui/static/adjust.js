// The Adjust page: live gauges of toe and camber per wheel against the specification (green
// inside, red outside, the target marked), total toe, thrust and the front toe against the
// thrust line, from the station's live stream (Server-Sent Events). Toe also in mm at the rim
// (the rim diameter x sin toe, computed by the station: station/ui/units.py). Caster, SAI and
// included angle of the front wheels from the job's newest steering sweep, with its age: they
// are not followed live (docs/ui.md); the card says when a wheel's live camber has moved since.
"use strict";
let source = null, last = null, sweep = null;
const SVG = "http://www.w3.org/2000/svg";
function svgEl(tag, attrs) { const e = document.createElementNS(SVG, tag); for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v); return e; }
function gauge(id, label) {
  const g = Station.el("div", { class: "gauge none", id });
  g.appendChild(Station.el("div", { class: "label" }, label));
  const v = Station.el("div", { class: "value" }, "–");
  g.appendChild(v);
  const svg = svgEl("svg", { viewBox: "0 0 400 46", preserveAspectRatio: "none" });
  svg.appendChild(svgEl("rect", { class: "track", x: 0, y: 8, width: 400, height: 20 }));
  svg.appendChild(svgEl("rect", { class: "band-ok", x: 0, y: 8, width: 0, height: 20 }));
  svg.appendChild(svgEl("line", { class: "target", x1: 200, x2: 200, y1: 2, y2: 34 }));
  svg.appendChild(svgEl("line", { class: "needle", x1: 200, x2: 200, y1: 0, y2: 36 }));
  for (const [cls, x, anchor] of [["tick lo", 2, "start"], ["tick hi", 398, "end"]]) {
    const t = svgEl("text", { class: cls, x, y: 45, "text-anchor": anchor }); svg.appendChild(t);
  }
  g.appendChild(svg);
  return g;
}
function setGauge(g, a) {
  const value = a ? a.value : null;
  g.className = `gauge ${Station.verdictClass(a ? a.ok : null)}`;
  g.dataset.value = value === null ? "" : value;
  const v = g.querySelector(".value");
  v.textContent = Station.angle(value, 3) + " ";
  if (a && a.std !== null && value !== null) v.appendChild(Station.el("span", { class: "pm" }, Station.pm(a.std)));
  g.dataset.mm = a && a.mm !== null && a.mm !== undefined ? a.mm : "";
  if (a && a.mm !== null && a.mm !== undefined && value !== null) v.appendChild(Station.el("span", { class: "mm" }, Station.mm(a.mm)));
  const w = a && a.window;
  const centre = w ? w.nominal : (value || 0), half = w ? Math.max(3 * (w.high - w.nominal), 0.1) : 1.0;
  const x = (d) => Math.min(400, Math.max(0, 200 + 200 * (d - centre) / half));
  const band = g.querySelector(".band-ok"), target = g.querySelector(".target");
  if (w) { band.setAttribute("x", x(w.low)); band.setAttribute("width", x(w.high) - x(w.low)); target.setAttribute("x1", x(w.nominal)); target.setAttribute("x2", x(w.nominal)); }
  else { band.setAttribute("width", 0); }
  target.style.display = w ? "" : "none";
  const needle = g.querySelector(".needle");
  needle.style.display = value === null ? "none" : "";
  if (value !== null) { needle.setAttribute("x1", x(value)); needle.setAttribute("x2", x(value)); }
  g.querySelector(".lo").textContent = Station.angle(centre - half);
  g.querySelector(".hi").textContent = Station.angle(centre + half);
}
function build() {
  const box = document.getElementById("gauges");
  box.textContent = "";
  for (const w of ["FL", "FR", "RL", "RR"]) {
    const card = Station.el("div", { class: "card wheel-card", id: `wheel-${w}` });
    card.appendChild(Station.el("h2", {}, { FL: "front left", FR: "front right", RL: "rear left", RR: "rear right" }[w] + ` (${w})`));
    card.appendChild(Station.el("div", { class: "note" }));
    card.appendChild(gauge(`g-${w}-toe`, "toe (+ in)"));
    card.appendChild(gauge(`g-${w}-camber`, "camber (+ top out)"));
    if (w[0] === "F") card.appendChild(Station.el("div", { class: "thrust-toe" }, "toe against the thrust line: –"));
    box.appendChild(card);
  }
  const totals = document.getElementById("totals");
  totals.textContent = "";
  for (const [id, label] of [["g-front-total", "front total toe"], ["g-rear-total", "rear total toe"], ["g-thrust", "thrust angle (+ right)"]]) {
    const card = Station.el("div", { class: "card" }); card.appendChild(gauge(id, label)); totals.appendChild(card);
  }
}
function sweepAge(timeUtc) {
  const t = new Date(timeUtc), minutes = Math.max(0, Math.round((Date.now() - t.getTime()) / 60000));
  const hhmm = `${String(t.getHours()).padStart(2, "0")}:${String(t.getMinutes()).padStart(2, "0")}`;
  return `${hhmm} (${minutes < 1 ? "just now" : minutes < 120 ? `${minutes} min ago` : `${Math.round(minutes / 60)} h ago`})`;
}
function buildCaster() {
  const box = document.getElementById("caster");
  box.textContent = "";
  if (!sweep || !sweep.sweep) return;
  for (const [w, v] of Object.entries(sweep.sweep.wheels)) {
    const card = Station.el("div", { class: "card wheel-card", id: `caster-${w}` });
    card.appendChild(Station.el("h2", {}, `${w === "FL" ? "front left" : "front right"} (${w})`));
    card.appendChild(Station.el("div", { class: "note" }, ""));
    card.appendChild(gauge(`g-${w}-caster`, "caster (+ top rearward)"));
    card.appendChild(gauge(`g-${w}-sai`, "SAI (+ top inward)"));
    card.appendChild(Station.el("div", { class: "included" }));
    box.appendChild(card);
    setGauge(card.querySelector(`#g-${w}-caster`), v.caster);
    setGauge(card.querySelector(`#g-${w}-sai`), v.sai);
    card.querySelector(".included").textContent = `included angle: ${Station.angle(v.included_angle.value, 2)} ${Station.pm(v.included_angle.std)}`;
  }
}
// Whether a front wheel's live camber has left its camber at the sweep (then the suspension was
// adjusted and caster may have moved with it): beyond 3 sigma of the two, at least 0.05 deg.
function casterNotes(m) {
  const notes = {};
  if (!sweep || !sweep.sweep) return notes;
  for (const [w, v] of Object.entries(sweep.sweep.wheels)) {
    const live = m && m.wheels[w] ? m.wheels[w].camber : null, then = v.camber_at_sweep;
    let note = "as at the sweep; caster does not follow live";
    if (live && live.value !== null && m.wheels[w].live && Boolean(m.runout_compensated) === Boolean(sweep.sweep.runout_compensated)) {
      const moved = live.value - then.value, limit = Math.max(0.05, 3 * Math.hypot(live.std || 0, then.std || 0));
      if (Math.abs(moved) > limit) note = `camber has moved ${Station.angle(moved, 2)} since the sweep: the suspension was adjusted, caster may have moved too; run the sweep again`;
      else note = `camber as at the sweep (${Station.angle(moved, 2)}); caster does not follow live: after turning the caster adjuster run the sweep again`;
    }
    notes[w] = note;
    const el = document.querySelector(`#caster-${w} .note`);
    if (el) { el.textContent = note; el.className = `note ${note.startsWith("camber has moved") ? "out-text" : ""}`; }
  }
  return notes;
}
async function loadSweep() {
  const r = await Station.api("/api/adjust/steering");
  if (!r.ok) return;
  const changed = JSON.stringify(r.data) !== JSON.stringify(sweep);
  sweep = r.data;
  const line = document.getElementById("sweep-line");
  if (sweep.sweep) {
    line.textContent = `From the steering sweep at ${sweepAge(sweep.sweep.time_utc)} (±${sweep.sweep.sweep_deg} deg, cycle ${sweep.sweep.cycle_id}). Re-run the sweep after adjusting caster.`;
    line.dataset.cycle = sweep.sweep.cycle_id;
  } else { line.textContent = sweep.message; line.dataset.cycle = ""; }
  document.getElementById("rerun-sweep").textContent = sweep.sweep ? "Run the steering sweep again" : "Run the steering sweep";
  if (changed) buildCaster();
  casterNotes(last);
}
async function rerunSweep() {
  const msg = document.getElementById("sweep-message");
  const r = await Station.api("/api/steps/steering/start", { method: "POST" });
  if (!r.ok) { Station.message(msg, "error", r.data.error, r.data.hint); return; }
  Station.message(msg, "info", "The steering sweep runs: steer as the Procedure page shows (the live values pause meanwhile).");
  const a = Station.el("a", { href: "/procedure" }, " Open the Procedure page"); msg.appendChild(a);
}
function show(m) {
  last = m;
  casterNotes(m);
  for (const [w, v] of Object.entries(m.wheels)) {
    setGauge(document.getElementById(`g-${w}-toe`), v.toe);
    setGauge(document.getElementById(`g-${w}-camber`), v.camber);
    const note = document.querySelector(`#wheel-${w} .note`);
    const rim = v.rim_diameter_mm ? ` · toe in mm at the ${v.rim_diameter_mm.toFixed(1)} mm rim` : "";
    note.textContent = (v.error ? `no reading: ${v.error}` : v.live ? "live" : "held from the full measurement (not on the live axle)") + rim;
    note.className = `note ${v.error ? "out-text" : ""}`;
    const tt = document.querySelector(`#wheel-${w} .thrust-toe`);
    if (tt) tt.textContent = `toe against the thrust line: ${Station.angle(v.toe_thrust, 3)}`;
  }
  setGauge(document.getElementById("g-front-total"), m.axles.front);
  setGauge(document.getElementById("g-rear-total"), m.axles.rear);
  setGauge(document.getElementById("g-thrust"), m.thrust);
  const rate = document.getElementById("rate");
  rate.textContent = `${m.rate_hz.toFixed(1)} updates/s`;
  rate.dataset.updates = String((Number(rate.dataset.updates) || 0) + 1);
}
function connect() {
  if (source) source.close();
  const axle = document.getElementById("axle").value;
  source = new EventSource(`/api/live/stream?axle=${axle}`);
  const status = document.getElementById("status");
  source.addEventListener("status", (e) => {
    const s = JSON.parse(e.data);
    Station.message(status, s.state === "error" ? "error" : s.state === "live" ? "good" : "info", `${s.state}: ${s.message}`, s.hint);
    status.dataset.state = s.state;
    if (s.state === "live") loadSweep();  // after a step (a new sweep) the live view comes back
    const warnings = document.getElementById("warnings");
    warnings.textContent = "";
    if (s.state === "live") warnings.appendChild(warningList(s.warnings || []));
  });
  source.onmessage = (e) => show(JSON.parse(e.data));
  source.onerror = () => { Station.message(status, "error", "the connection to the station was lost; reconnecting…"); };
}
document.addEventListener("DOMContentLoaded", async () => {
  build();
  await Station.session();
  const r = await Station.api("/api/job");
  if (r.ok && r.data.spec) document.getElementById("vehicle").textContent = `spec: ${r.data.spec.name}`;
  document.getElementById("axle").addEventListener("change", () => { build(); connect(); });
  document.addEventListener("units", () => { if (last) show(last); buildCaster(); casterNotes(last); });
  document.getElementById("rerun-sweep").addEventListener("click", rerunSweep);
  await loadSweep();
  setInterval(loadSweep, 10000);  // the sweep's age; a sweep run elsewhere (the command line, a PLC)
  connect();
});
