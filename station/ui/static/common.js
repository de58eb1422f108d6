// What every page of the station's screen shares: the session (CSRF token), requests, messages,
// angle formatting (decimal degrees, or degrees and minutes as the shop chooses), the menu.
"use strict";
const Station = {
  csrf: null,
  async session() {
    const r = await this.api("/api/session");
    if (r.ok) { this.csrf = r.data.csrf; }
    return r;
  },
  async api(path, options = {}) {
    const init = { method: options.method || "GET", headers: {}, credentials: "same-origin" };
    if (init.method !== "GET") {
      init.headers["X-CSRF-Token"] = this.csrf || "";
      init.headers["Content-Type"] = "application/json";
      init.body = JSON.stringify(options.body || {});
    }
    let response;
    try { response = await fetch(path, init); } catch (e) {
      return { ok: false, status: 0, data: { error: "the station does not answer", hint: "check that `station ui` runs; the page retries" } };
    }
    if (response.status === 401 && path !== "/login") { window.location.href = "/login"; }
    let data = {};
    try { data = await response.json(); } catch (e) { data = { error: `the station answered ${response.status}` }; }
    return { ok: response.ok, status: response.status, data };
  },
  message(el, kind, text, hint) {
    el.className = `message ${kind}`;
    el.textContent = text;
    if (hint) { const h = document.createElement("span"); h.className = "hint"; h.textContent = `What to do: ${hint}`; el.appendChild(h); }
  },
  clear(el) { el.className = "message hidden"; el.textContent = ""; },
  units() { return localStorage.getItem("station-units") || "deg"; },
  angle(value, digits = 2) {
    if (value === null || value === undefined) return "–";
    const sign = value < 0 ? "−" : "+";
    if (this.units() === "dm") {
      const total = Math.round(Math.abs(value) * 60);
      return `${sign}${Math.floor(total / 60)}°${String(total % 60).padStart(2, "0")}′`;
    }
    return `${sign}${Math.abs(value).toFixed(digits)}°`;
  },
  pm(std) {
    if (std === null || std === undefined) return "";
    return this.units() === "dm" ? `± ${Math.max(1, Math.round(std * 60))}′` : `± ${std.toFixed(3)}°`;
  },
  el(tag, attrs = {}, text) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) { if (k === "class") e.className = v; else e.setAttribute(k, v); }
    if (text !== undefined) e.textContent = text;
    return e;
  },
  verdictClass(ok) { return ok === true ? "ok" : ok === false ? "out" : "none"; },
};
document.addEventListener("DOMContentLoaded", () => {
  for (const a of document.querySelectorAll("header nav a")) {
    if (a.getAttribute("href") === window.location.pathname) a.classList.add("here");
  }
  const units = document.getElementById("units");
  if (units) {
    units.value = Station.units();
    units.addEventListener("change", () => { localStorage.setItem("station-units", units.value); document.dispatchEvent(new Event("units")); });
  }
});
