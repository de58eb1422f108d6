// What every page of the station's screen shares: the session (CSRF token), requests, messages,
// angle formatting (decimal degrees, or degrees and minutes as the shop chooses), the menu.
"use strict";
const Station = {
  csrf: null,
  async session() {
    const r = await this.api("/api/session");
    if (r.ok) {
      this.csrf = r.data.csrf;
      this.angleDefault = r.data.angle_format === "dms" ? "dms" : "decimal";
      const units = document.getElementById("units");
      if (units) units.value = this.units();
    }
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
    if (response.status === 403 && init.method !== "GET" && !options.retried) {
      // the token of another session than the cookie's (the station restarted, or requests sent
      // before the page's cookie was set each opened one): take the cookie's session's token, once
      const before = this.csrf;
      await this.session();
      if (this.csrf && this.csrf !== before) return this.api(path, { ...options, retried: true });
    }
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
  angleDefault: "decimal",  // ui.angle_format of the configuration, until this browser chooses
  units() {
    const chosen = localStorage.getItem("station-angle-format");
    return chosen === "decimal" || chosen === "dms" ? chosen : this.angleDefault;
  },
  // the same rules as station/ui/units.py: whole minutes, rounded; no sign on a value that rounds to zero
  angle(value, digits = 2) {
    if (value === null || value === undefined || !Number.isFinite(value)) return "–";
    if (this.units() === "dms") {
      const total = Math.round(Math.abs(value) * 60);
      return `${value < 0 && total ? "−" : "+"}${Math.floor(total / 60)}°${String(total % 60).padStart(2, "0")}′`;
    }
    const text = Math.abs(value).toFixed(digits);
    return `${value < 0 && Number(text) !== 0 ? "−" : "+"}${text}°`;
  },
  mm(value) {
    if (value === null || value === undefined || !Number.isFinite(value)) return "";
    return `${value < 0 && value !== 0 ? "−" : "+"}${Math.abs(value).toFixed(1)} mm`;
  },
  pm(std) {
    if (std === null || std === undefined) return "";
    return this.units() === "dms" ? `± ${Math.max(1, Math.round(std * 60))}′` : `± ${std.toFixed(3)}°`;
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
    units.addEventListener("change", () => { localStorage.setItem("station-angle-format", units.value); document.dispatchEvent(new Event("units")); });
  }
});
