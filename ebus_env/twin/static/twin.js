// The twin's dashboard: polls the twin's JSON API every 2 s (no reload); the read token comes
// once in the URL (?token=...) and is kept for the tab in sessionStorage.
"use strict";
const params = new URLSearchParams(location.search);
if (params.get("token")) sessionStorage.setItem("twinToken", params.get("token"));
if (params.get("fleet")) sessionStorage.setItem("twinFleet", params.get("fleet"));
const token = sessionStorage.getItem("twinToken");
const fleet = sessionStorage.getItem("twinFleet");
const page = document.body.dataset.page;

async function get(path) {
  const r = await fetch(path, {headers: {"Authorization": "Bearer " + token}});
  if (!r.ok) throw new Error(r.status + " " + (await r.text()));
  return r.json();
}
const clock = (t) => t == null ? "-" : new Date(t * 1000).toISOString().slice(0, 19).replace("T", " ");
const pct = (x) => x == null ? "-" : x.toFixed(1) + " %";
function cell(tr, text, cls) { const td = tr.insertCell(); td.textContent = text; if (cls) td.className = cls; return td; }

async function fleetPage() {
  document.getElementById("fleet").textContent = fleet;
  const data = await get(`/v1/fleets/${encodeURIComponent(fleet)}/buses`);
  const body = document.querySelector("#buses tbody");
  body.replaceChildren();
  for (const b of data.buses) {
    const tr = body.insertRow();
    tr.dataset.bus = b.bus;
    tr.className = (b.state === "stale" ? "stale " : "") + (b.alarms ? "alarm" : "");
    const a = document.createElement("a");
    a.href = "/bus/" + encodeURIComponent(b.bus); a.textContent = b.bus;
    tr.insertCell().appendChild(a);
    cell(tr, b.state, "state state-" + b.state);
    cell(tr, clock(b.last_t) + (b.seen_s_ago != null ? ` (${Math.round(b.seen_s_ago)} s ago)` : ""));
    cell(tr, pct(b.soc_pct), "soc");
    cell(tr, pct(b.predicted_end_soc_pct), "end");
    cell(tr, b.predicted_end_band_pct ? b.predicted_end_band_pct.map((x) => x.toFixed(1)).join("-") + " %" : "-");
    cell(tr, String(b.alarms), "alarms");
    cell(tr, b.latest_alarm || "", "latest-alarm");
  }
  document.getElementById("status").textContent = `${data.buses.length} buses, updated ${new Date().toLocaleTimeString()}`;
}

function plot(svg, measured, prediction, reserve) {
  const pts = measured.t.map((t, i) => [t, measured.soc_pct[i]]).filter((p) => p[1] != null);
  const ahead = prediction ? [[prediction.data_t, prediction.end_soc_pct], [prediction.end_t, prediction.end_soc_pct]] : [];
  const all = pts.concat(ahead);
  svg.replaceChildren();
  if (!all.length) return;
  const t0 = Math.min(...all.map((p) => p[0])), t1 = Math.max(...all.map((p) => p[0])) + 1;
  const x = (t) => 40 + 840 * (t - t0) / (t1 - t0), y = (s) => 240 - 2.2 * s;
  const ns = "http://www.w3.org/2000/svg";
  const line = (p, color, dash) => { const e = document.createElementNS(ns, "polyline");
    e.setAttribute("points", p.map((q) => `${x(q[0])},${y(q[1])}`).join(" "));
    e.setAttribute("fill", "none"); e.setAttribute("stroke", color); e.setAttribute("stroke-width", "2");
    if (dash) e.setAttribute("stroke-dasharray", "6 4"); svg.appendChild(e); };
  line([[t0, reserve], [t1, reserve]], "#c00", true);
  line(pts, "#1f77b4");
  if (prediction) {
    const p0 = [prediction.data_t, pts.length ? pts[pts.length - 1][1] : prediction.end_soc_pct];
    line([p0, [prediction.end_t, prediction.end_soc_pct]], "#ff7f0e");
    line([p0, [prediction.end_t, prediction.band_pct[0]]], "#ffbb78", true);
    line([p0, [prediction.end_t, prediction.band_pct[1]]], "#ffbb78", true);
  }
  svg.dataset.points = String(pts.length);
}

async function busPage() {
  const bus = decodeURIComponent(location.pathname.split("/").pop());
  document.getElementById("bus").textContent = bus;
  document.getElementById("back").href = `/?fleet=${encodeURIComponent(fleet || "")}`;
  const d = await get(`/v1/buses/${encodeURIComponent(bus)}`);
  plot(document.getElementById("soc"), d.measured, d.prediction, d.reserve_soc_pct);
  const p = d.prediction;
  document.getElementById("prediction").textContent = p ?
    `SoC now ${pct(d.soc_pct)}; block end ${pct(p.end_soc_pct)} (90 % band ${p.band_pct.map((v) => v.toFixed(1)).join("-")} %), ` +
    p.chargers.map((c) => `at ${c.site} ${clock(c.t)}: ${pct(c.soc_pct)}`).join("; ") : "no prediction yet";
  const ul = document.getElementById("alarms"); ul.replaceChildren();
  for (const a of d.alarms) { const li = document.createElement("li"); li.className = "alarm";
    li.textContent = `${a.day} [${a.kind}] ${a.message}`; ul.appendChild(li); }
  const dg = document.querySelector("#diagnoses tbody"); dg.replaceChildren();
  for (const x of d.diagnoses) { const tr = dg.insertRow(); cell(tr, x.day); cell(tr, x.finding); cell(tr, x.status); cell(tr, x.why); }
  const ft = document.querySelector("#fits tbody"); ft.replaceChildren();
  for (const f of d.fits) { const tr = ft.insertRow(); const v = f.values;
    const num = (k, n) => v[k] == null ? "-" : v[k].toFixed(n);
    cell(tr, clock(f.fitted_at)); cell(tr, f.kind); cell(tr, clock(f.t_from) + " - " + clock(f.t_to));
    cell(tr, num("static_rcd.rcd_frac", 3)); cell(tr, num("auxiliaries.base_power_w", 0));
    cell(tr, num("rolling_resistance.rolling_coef", 4)); cell(tr, num("efficiency_map.gearbox_efficiency", 3));
    cell(tr, f.nrmse == null ? "-" : f.nrmse.toFixed(4)); }
  document.getElementById("status").textContent = `updated ${new Date().toLocaleTimeString()}`;
}

async function tick() {
  try { await (page === "fleet" ? fleetPage() : busPage()); }
  catch (e) { document.getElementById("status").textContent = "error: " + e.message; }
  setTimeout(tick, 2000);
}
tick();
