"use strict";
document.getElementById("login").addEventListener("submit", async (event) => {
  event.preventDefault();
  const msg = document.getElementById("message");
  msg.className = "message info"; msg.textContent = "checking…";
  let r;
  try {
    r = await fetch("/login", { method: "POST", headers: { "Content-Type": "application/json" }, credentials: "same-origin",
                                body: JSON.stringify({ password: document.getElementById("password").value }) });
  } catch (e) { msg.className = "message error"; msg.textContent = "the station does not answer"; return; }
  if (r.ok) { window.location.href = "/"; return; }
  let data = {}; try { data = await r.json(); } catch (e) { /* not JSON */ }
  msg.className = "message error";
  msg.textContent = data.error || `refused (${r.status})`;
  if (data.hint) { const h = document.createElement("span"); h.className = "hint"; h.textContent = `What to do: ${data.hint}`; msg.appendChild(h); }
});
