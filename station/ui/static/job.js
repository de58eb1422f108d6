// The Job page: the job id / VIN and the vehicle, searched in the specification list.
"use strict";
let chosen = null;
async function search() {
  const q = document.getElementById("vehicle-search").value;
  const r = await Station.api(`/api/vehicles?q=${encodeURIComponent(q)}`);
  const list = document.getElementById("vehicle-list");
  list.textContent = "";
  if (!r.ok) { Station.message(document.getElementById("message"), "error", r.data.error, r.data.hint); return; }
  if (!r.data.vehicles.length) { list.appendChild(Station.el("p", {}, `no vehicle matches “${q}”`)); }
  for (const v of r.data.vehicles) {
    const item = Station.el("div", { "data-key": v.key, class: v.key === chosen ? "chosen" : "" }, `${v.name}  (${v.key})`);
    item.addEventListener("click", () => { chosen = v.key; document.getElementById("vehicle-chosen").textContent = v.name; search(); });
    list.appendChild(item);
  }
}
function showSpec(spec) {
  const card = document.getElementById("spec-card");
  if (!spec) { card.classList.add("hidden"); return; }
  card.classList.remove("hidden");
  document.getElementById("spec-name").textContent = spec.name;
  const body = document.querySelector("#spec-table tbody");
  body.textContent = "";
  for (const [name, w] of Object.entries(spec.windows)) {
    if (!w) continue;
    const tr = Station.el("tr");
    tr.appendChild(Station.el("td", {}, name));
    tr.appendChild(Station.el("td", { class: "num" }, Station.angle(w.nominal)));
    tr.appendChild(Station.el("td", { class: "num" }, `${Station.angle(w.low)} … ${Station.angle(w.high)}`));
    body.appendChild(tr);
  }
}
async function load() {
  await Station.session();
  const r = await Station.api("/api/job");
  if (r.ok && r.data.job) {
    document.getElementById("job-id").value = r.data.job.job_id;
    chosen = r.data.job.vehicle;
    document.getElementById("vehicle-chosen").textContent = r.data.spec ? r.data.spec.name : "none";
    showSpec(r.data.spec);
  }
  search();
}
document.addEventListener("DOMContentLoaded", () => {
  document.getElementById("vehicle-search").addEventListener("input", search);
  document.getElementById("save-job").addEventListener("click", async () => {
    const msg = document.getElementById("message");
    const r = await Station.api("/api/job", { method: "POST", body: { job_id: document.getElementById("job-id").value, vehicle: chosen } });
    if (!r.ok) { Station.message(msg, "error", r.data.error, r.data.hint); return; }
    Station.message(msg, "good", `Job ${r.data.job.job_id} started${r.data.spec ? ` for a ${r.data.spec.name}` : " (no vehicle spec: values without pass/fail)"}. Next: the Procedure page.`);
    showSpec(r.data.spec);
  });
  document.addEventListener("units", load);
  load();
});
