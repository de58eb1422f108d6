// The Procedure page: the steps in order, start one, follow its progress and see its result.
// The station streams the steps (Server-Sent Events, /api/steps/stream): each message has the new
// progress lines of the running step only; on a reconnect the browser's Last-Event-ID resumes them.
"use strict";
let shownRun = null, built = false, source = null;
function buildSteps(steps) {
  const box = document.getElementById("steps");
  box.textContent = "";
  steps.forEach((s, i) => {
    const card = Station.el("div", { class: "card step", id: `step-${s.key}` });
    card.appendChild(Station.el("div", { class: "num" }, String(i + 1)));
    const text = Station.el("div");
    const title = Station.el("strong", {}, s.title);
    text.appendChild(title);
    text.appendChild(Station.el("span", { class: "badge state" }, s.available ? "not run" : "not available"));
    text.appendChild(Station.el("p", {}, s.instruction));
    text.appendChild(Station.el("small", {}, `from the command line: ${s.command}`));
    card.appendChild(text);
    const button = Station.el("button", { "data-key": s.key }, "Start");
    button.disabled = !s.available;
    button.addEventListener("click", () => start(s.key));
    card.appendChild(button);
    box.appendChild(card);
  });
  built = true;
}
async function start(key) {
  const msg = document.getElementById("message");
  const r = await Station.api(`/api/steps/${key}/start`, { method: "POST" });
  if (!r.ok) { Station.message(msg, "error", r.data.error, r.data.hint); return; }
  Station.clear(msg);
}
function showRun(run) {
  const log = document.getElementById("log");
  if (!run) return;
  const id = `${run.key}@${run.started_utc}`;
  if (shownRun !== id) {  // another run: the stream sends it from its first line
    shownRun = id; log.textContent = ""; document.getElementById("result").textContent = "";
  }
  document.getElementById("running-title").textContent = `— ${run.title} (${run.state})`;
  for (const line of run.lines) log.appendChild(Station.el("div", { class: "line" }, line));
  if (run.lines.length) log.scrollTop = log.scrollHeight;
  const outcome = document.getElementById("outcome");
  if (run.state === "running") { Station.clear(outcome); return; }
  if (run.state === "done") Station.message(outcome, "good", `${run.title}: done.`);
  else Station.message(outcome, "error", `${run.title} ${run.state === "error" ? "stopped by an error" : "failed"}${run.code ? ` (error ${run.code})` : ""}: ${run.message}`, run.hint);
  const result = document.getElementById("result");
  const s = run.summary;
  if (!result.firstChild && s && (s.valid || (s.refused && s.refused.length))) result.appendChild(resultTable(s));
}
function update(data) {
  if (!built) buildSteps(data.steps);
  const job = data.job;
  document.getElementById("job-line").textContent = job ? `Job: ${job.job_id}   vehicle: ${job.vehicle || "no spec"}` : "No job yet: enter it on the Job page first.";
  const running = data.current && data.current.state === "running";
  for (const s of data.steps) {
    const card = document.getElementById(`step-${s.key}`);
    const badge = card.querySelector(".state");
    const state = s.last ? s.last.state : (s.available ? "not run" : "not available");
    badge.textContent = state; badge.className = `badge state ${state}`;
    card.querySelector("button").disabled = !s.available || running || !job;
  }
  showRun(data.current);
}
function connect() {
  const msg = document.getElementById("message");
  source = new EventSource("/api/steps/stream");
  source.onmessage = (e) => { if (msg.dataset.lost) { Station.clear(msg); delete msg.dataset.lost; } update(JSON.parse(e.data)); };
  source.onerror = () => { Station.message(msg, "error", "the connection to the station was lost; reconnecting…", "a running step goes on without this page"); msg.dataset.lost = "1"; };
}
document.addEventListener("DOMContentLoaded", async () => {
  await Station.session();
  connect();
});
