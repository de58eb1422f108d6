// The History page: stored cycles, each job's report (HTML) and its PDF.
"use strict";
async function load() {
  const job = document.getElementById("job-filter").value;
  const r = await Station.api(`/api/history${job ? `?job=${encodeURIComponent(job)}` : ""}`);
  const msg = document.getElementById("message");
  if (!r.ok) { Station.message(msg, "error", r.data.error, r.data.hint); return; }
  Station.clear(msg);
  const select = document.getElementById("job-filter");
  if (select.options.length === 1) {
    for (const j of r.data.jobs) select.appendChild(Station.el("option", { value: j.job_id }, `${j.shown} (${j.cycles} cycles, last ${j.last_utc})`));
    if (!r.data.jobs.length) Station.message(msg, "info", "No job measured yet.");
  }
  for (const [id, suffix] of [["report-link", ""], ["pdf-link", ".pdf"]]) {
    const a = document.getElementById(id);
    a.classList.toggle("hidden", !job);
    a.href = `/history/report${suffix}?job=${encodeURIComponent(job)}`;
  }
  const body = document.querySelector("#cycles tbody");
  body.textContent = "";
  for (const c of r.data.cycles.slice().reverse()) {
    const tr = Station.el("tr", { "data-cycle": c.cycle_id });
    tr.appendChild(Station.el("td", {}, c.time_utc));
    tr.appendChild(Station.el("td", {}, c.job_id));
    tr.appendChild(Station.el("td", {}, c.vehicle || "–"));
    const verdict = !c.valid ? `FAILED: ${c.failure || ""}` : c.passed === true ? "PASS" : c.passed === false ? "FAIL" : "measured";
    tr.appendChild(Station.el("td", { class: !c.valid || c.passed === false ? "out" : c.passed ? "ok" : "" }, verdict + (c.runout_compensated ? " · runout comp." : "") + (c.steering ? " · steering" : "")));
    for (const n of ["FL.toe", "FR.toe", "RL.toe", "RR.toe", "thrust"]) tr.appendChild(Station.el("td", { class: "num" }, Station.angle(c.angles[n], 3)));
    body.appendChild(tr);
  }
}
document.addEventListener("DOMContentLoaded", async () => {
  await Station.session();
  document.getElementById("job-filter").addEventListener("change", load);
  document.addEventListener("units", load);
  load();
});
