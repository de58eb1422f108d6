// A measurement's values as a table (the Procedure page's result; shared).
"use strict";
function warningList(warnings) {
  // The warnings, folded: a count to open (the table stays in view).
  const d = Station.el("details", { class: "warnings" });
  d.appendChild(Station.el("summary", { class: warnings.length ? "warn" : "" }, warnings.length ? `${warnings.length} warning(s)` : "no warning"));
  for (const w of warnings) d.appendChild(Station.el("p", { class: "warn" }, w));
  return d;
}
function resultTable(summary) {
  const wrap = Station.el("div", { class: "card", id: "result-card" });
  if (!summary) return wrap;
  wrap.appendChild(Station.el("h2", {}, `Cycle ${summary.cycle_id || ""}${summary.overall === true ? " — PASS" : summary.overall === false ? " — FAIL" : ""}`));
  if (!summary.valid) {
    // a cycle refused for uncertain wheels: each wheel and why (what to do is in the message above)
    if (summary.refused && summary.refused.length) {
      wrap.appendChild(Station.el("p", {}, "No angle of this cycle is valid. These wheels are less certain than the limit:"));
      const table = Station.el("table", { id: "refused-table" });
      const head = Station.el("tr");
      for (const h of ["wheel", "why"]) head.appendChild(Station.el("th", {}, h));
      table.appendChild(head);
      for (const r of summary.refused) {
        const tr = Station.el("tr", { "data-wheel": r.wheel, "data-reason": r.reason || "" });
        tr.appendChild(Station.el("td", {}, r.wheel)); tr.appendChild(Station.el("td", { class: "warn" }, r.why));
        table.appendChild(tr);
      }
      wrap.appendChild(table);
    }
    return wrap;
  }
  wrap.appendChild(Station.el("p", {}, summary.runout_compensated ? "Toe and camber of the wheels' spin axes (runout compensated)." : "Toe and camber of the rim planes (runout not compensated)."));
  const table = Station.el("table", { id: "result-table" });
  const runout = Boolean(summary.runout_compensated);  // then each rim's runout (its tilt against the spin axis) too
  const head = Station.el("tr");
  for (const h of ["wheel", "toe", "camber"].concat(runout ? ["rim runout"] : [])) head.appendChild(Station.el("th", {}, h));
  table.appendChild(head);
  const cell = (a) => Station.el("td", { class: `num ${Station.verdictClass(a.ok)}`, "data-value": a.value }, `${Station.angle(a.value, 3)} ${Station.pm(a.std)}`);
  for (const [w, v] of Object.entries(summary.wheels)) {
    const tr = Station.el("tr", { "data-wheel": w });
    tr.appendChild(Station.el("td", {}, w)); tr.appendChild(cell(v.toe)); tr.appendChild(cell(v.camber));
    if (runout) tr.appendChild(Station.el("td", { class: "num runout", "data-value": v.runout_deg }, Station.angle(v.runout_deg, 3).replace("+", "")));
    table.appendChild(tr);
  }
  for (const [axle, a] of Object.entries(summary.axles)) {
    const tr = Station.el("tr"); tr.appendChild(Station.el("td", {}, `${axle} total toe`)); tr.appendChild(cell(a)); tr.appendChild(Station.el("td"));
    if (runout) tr.appendChild(Station.el("td"));
    table.appendChild(tr);
  }
  const tr = Station.el("tr"); tr.appendChild(Station.el("td", {}, "thrust angle")); tr.appendChild(cell(summary.thrust)); tr.appendChild(Station.el("td"));
  if (runout) tr.appendChild(Station.el("td"));
  table.appendChild(tr);
  wrap.appendChild(table);
  if (summary.steering) {
    const st = Station.el("table", { id: "steering-table" });
    const h = Station.el("tr"); for (const x of ["front wheel", "caster", "SAI", "included angle"]) h.appendChild(Station.el("th", {}, x)); st.appendChild(h);
    for (const [w, s] of Object.entries(summary.steering)) {
      const r = Station.el("tr", { "data-wheel": w }); r.appendChild(Station.el("td", {}, w));
      for (const k of ["caster", "sai", "included_angle"]) r.appendChild(cell(s[k]));
      st.appendChild(r);
    }
    wrap.appendChild(Station.el("h2", {}, "Steering geometry")); wrap.appendChild(st);
  }
  wrap.appendChild(warningList(summary.warnings || []));
  return wrap;
}
