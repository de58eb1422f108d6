// The Cameras page: run a camera check, then each camera's image with its rim drawn and warnings.
"use strict";
let timer = null;
function render(data) {
  const box = document.getElementById("cams");
  box.textContent = "";
  const run = data.check;
  const msg = document.getElementById("message");
  if (!run) { Station.message(msg, "info", "No check yet: press the button (the cameras capture once)."); }
  else if (run.state === "running") { Station.message(msg, "info", `checking… ${run.lines.length ? run.lines[run.lines.length - 1] : ""}`); }
  else if (run.state !== "done") { Station.message(msg, "error", `the check failed: ${run.message}`, run.hint); }
  else { Station.message(msg, "good", `checked at ${run.finished_utc}`); }
  for (const [cid, c] of Object.entries(data.configured)) {
    const card = Station.el("div", { class: "card cam", id: `cam-${cid}` });
    card.appendChild(Station.el("h2", {}, `${cid} · ${c.wheel} · ${c.resolution.join("×")}`));
    const info = run && run.state === "done" && run.summary ? run.summary.cameras[cid] : null;
    if (info && info.image) card.appendChild(Station.el("img", { src: `/api/cameras/${cid}.png?t=${encodeURIComponent(run.finished_utc)}`, alt: `${cid} with its rim` }));
    if (info) {
      card.appendChild(Station.el("p", { class: info.ok ? "ok-text" : "out-text" }, info.ok ? `rim found (semi-axes ${info.rim_axes_px.join(", ")} px)` : `no rim: ${info.reason || "not found"}`));
      for (const w of info.warnings) card.appendChild(Station.el("p", { class: "warn" }, `warning: ${w}`));
      if (info.ok && !info.warnings.length) card.appendChild(Station.el("p", {}, "exposure and focus: no warning"));
    }
    box.appendChild(card);
  }
  if (run && run.state === "running" && !timer) timer = setTimeout(() => { timer = null; load(); }, 700);
}
async function load() {
  const r = await Station.api("/api/cameras");
  if (r.ok) render(r.data); else Station.message(document.getElementById("message"), "error", r.data.error, r.data.hint);
}
document.addEventListener("DOMContentLoaded", async () => {
  await Station.session();
  document.getElementById("check").addEventListener("click", async () => {
    const r = await Station.api("/api/cameras/check", { method: "POST" });
    if (!r.ok) { Station.message(document.getElementById("message"), "error", r.data.error, r.data.hint); return; }
    load();
  });
  load();
});
