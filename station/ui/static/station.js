// The Station page: calibration age and health, PLC, what runs now, the cameras.
"use strict";
async function load() {
  const r = await Station.api("/api/station");
  const msg = document.getElementById("message");
  if (!r.ok) { Station.message(msg, "error", r.data.error, r.data.hint); return; }
  const d = r.data;
  const cal = document.getElementById("calibration");
  cal.textContent = d.calibration.ok ? `calibration ${d.calibration.id}, made ${d.calibration.created_utc} (${d.calibration.age_days} days ago)` : `no usable calibration: ${d.calibration.message}`;
  cal.className = d.calibration.ok ? "" : "out-text";
  const drift = document.getElementById("drift");
  drift.textContent = "";
  if (d.drift.cycle_id) {
    drift.appendChild(Station.el("p", { class: d.drift.warnings.length ? "out-text" : "ok-text" },
      d.drift.warnings.length ? `drift in the newest cycle (${d.drift.cycle_id}):` : `no drift warning in the newest cycle (${d.drift.cycle_id}, ${d.drift.time_utc})`));
    for (const w of d.drift.warnings) drift.appendChild(Station.el("p", { class: "warn" }, w));
  } else drift.appendChild(Station.el("p", {}, d.drift.message));
  const plc = document.getElementById("plc");
  plc.textContent = `${d.plc.message} (configured: ${d.plc.configured}; its cycles appear under History)`;
  plc.className = d.plc.heartbeat_advancing === true ? "ok-text" : d.plc.listening === false ? "" : "out-text";
  document.getElementById("now").textContent = (d.step ? `running: ${d.step.title}` : "no step running") + ` · live view: ${d.live.state}` + (d.simulated_seed !== null ? ` · simulated station, vehicle seed ${d.simulated_seed}` : "");
  const body = document.querySelector("#cameras tbody");
  body.textContent = "";
  for (const c of d.cameras) {
    const tr = Station.el("tr");
    for (const x of [c.id, c.wheel, c.role, c.uri, c.resolution.join("×")]) tr.appendChild(Station.el("td", {}, x));
    body.appendChild(tr);
  }
}
document.addEventListener("DOMContentLoaded", async () => { await Station.session(); load(); setInterval(load, 5000); });
