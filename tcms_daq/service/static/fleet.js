// TCMS-DAQ fleet page: GET /api/tests with filters and paging (X-Total-Count), per-run links, the overlay of two
// runs' loops (GET /api/tests/{id}/loop) and SPC (GET /api/spc/chart, /api/spc/bias). Results are shown as the
// API renders them (run.headline: "value ± U (k = …)" or "U not stated").
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const state = { offset: 0, total: 0, selected: [], runs: new Map() };

  const { t } = TcmsI18n;
  TcmsI18n.apply(document);
  TcmsI18n.bindSwitch($("lang"));
  const { withToken } = TcmsSession;
  const link = (path) => withToken(TcmsI18n.withLang(path));
  const esc = TcmsSession.escapeHtml;
  TcmsSession.bindTokenField($("f-token"), () => { search(); loadAudit(); });

  function message(text, isError) { $("message").textContent = text || ""; $("message").className = isError ? "error" : ""; }
  async function api(path) {
    const { data, response } = await TcmsSession.request("GET", path);
    // past 1 000 matches (store.base.EXACT_TOTAL_UP_TO) PostgreSQL estimates the total (X-Total-Count-Exact: false): shown as "≈ N"
    return { data, total: response.headers.get("X-Total-Count"),
             exact: response.headers.get("X-Total-Count-Exact") !== "false" };
  }
  function utc(local) { return local ? local + (local.length === 16 ? ":00" : "") + "Z" : ""; }  // datetime-local as UTC
  function width(el) { return Math.max(300, el.clientWidth - 4); }

  // a headline result as the API words it, "U not stated" in this page's language
  function shown(text) { return text ? text.replace("U not stated", t("res.u_not_stated")) : "—"; }

  // ---- the table ----
  function query() {
    const q = new URLSearchParams();
    const set = (k, v) => { if (v) q.set(k, v); };
    set("q", $("q").value.trim()); set("bench", $("f-bench").value.trim()); set("reducer", $("f-reducer").value.trim());
    set("serial", $("f-serial").value.trim()); set("status", $("f-status").value); set("verdict", $("f-verdict").value);
    set("since", utc($("f-since").value)); set("until", utc($("f-until").value));
    q.set("limit", $("f-limit").value); q.set("offset", state.offset); q.set("brief", "true");
    return q;
  }

  async function search() {
    let answer;
    try { answer = await api("/api/tests?" + query()); } catch (e) { message(e.message, true); return; }
    message("");
    state.total = parseInt(answer.total || "0", 10);
    const totalText = (answer.exact ? "" : "≈ ") + state.total;  // not `shown`: that names the cells' formatter
    $("total").textContent = totalText;
    const limit = parseInt($("f-limit").value, 10);
    const first = state.total ? state.offset + 1 : 0;
    $("page").textContent = t("fleet.page", { first, last: Math.min(state.offset + limit, state.total), total: totalText });
    $("prev").disabled = state.offset === 0;
    $("next").disabled = state.offset + limit >= state.total;
    const body = $("runs").tBodies[0];
    body.innerHTML = "";
    for (const r of answer.data) {
      state.runs.set(r.id, r);
      const id = encodeURIComponent(r.id);
      const file = (label, path) => `<a href="${esc(label === "report" || label === "certificate" ? link(path) : withToken(path))}" target="_blank">${esc(label === "report" ? t("dash.report") : label === "certificate" ? t("dash.certificate") : label)}</a>`;
      const h = r.headline || {};
      const tr = document.createElement("tr");
      tr.dataset.id = r.id;
      if (state.selected.includes(r.id)) tr.classList.add("selected");
      tr.innerHTML =
        `<td><input type="checkbox" class="pick" ${state.selected.includes(r.id) ? "checked" : ""}></td>` +
        `<td class="nowrap">${esc(r.id)}</td><td class="nowrap">${esc((r.created_at || "").replace("T", " ").slice(0, 19))}</td>` +
        `<td class="nowrap" title="${esc(r.bench_name)}">${esc(r.bench_id || "—")}</td><td class="nowrap">${esc(r.request.reducer)}</td>` +
        `<td class="nowrap">${esc(r.request.serial_number || "—")}</td><td class="nowrap">${esc(r.request.operator || "—")}</td>` +
        `<td class="nowrap">${esc(t("state." + r.status))}</td><td class="nowrap ${esc(r.verdict || "")}">${esc(r.verdict ? t("verdict." + r.verdict) : "—")}</td>` +
        `<td class="result">${esc(shown(h.rigidity_nm_per_arcmin))}</td><td class="result">${esc(shown(h.lost_motion_arcsec))}</td>` +
        `<td class="result">${esc(shown(h.backlash_arcsec))}</td>` +
        `<td class="files">${file("report", `/api/tests/${id}/report`)}${file("certificate", `/api/tests/${id}/certificate.pdf`)}` +
        `${file("CSV", `/api/tests/${id}/samples?format=csv`)}${file("JSON", `/api/tests/${id}/metadata`)}` +
        `${file("Parquet", `/api/tests/${id}/samples?format=parquet`)}${file("MDF4", `/api/tests/${id}/samples?format=mdf4`)}</td>`;
      body.appendChild(tr);
    }
    if (!answer.data.length) body.innerHTML = `<tr><td colspan="13" class="muted">${esc(t("fleet.none"))}</td></tr>`;
  }

  $("filters").addEventListener("submit", (ev) => { ev.preventDefault(); state.offset = 0; search(); });
  $("f-limit").addEventListener("change", () => { state.offset = 0; search(); });
  $("prev").addEventListener("click", () => { state.offset = Math.max(0, state.offset - parseInt($("f-limit").value, 10)); search(); });
  $("next").addEventListener("click", () => { state.offset += parseInt($("f-limit").value, 10); search(); });
  $("runs").addEventListener("change", (ev) => {
    if (!ev.target.classList.contains("pick")) return;
    const id = ev.target.closest("tr").dataset.id;
    state.selected = state.selected.filter((x) => x !== id);
    if (ev.target.checked) state.selected.push(id);
    while (state.selected.length > 2) state.selected.shift();
    for (const tr of $("runs").tBodies[0].rows) {
      const on = state.selected.includes(tr.dataset.id);
      tr.classList.toggle("selected", on);
      const box = tr.querySelector(".pick");
      if (box) box.checked = on;
    }
    overlay();
  });

  // ---- overlay of two loops ----
  const COLORS = ["#1f5fa8", "#d9771e"];
  let overlayPlot = null, overlayRequest = 0;
  async function overlay() {
    const ids = state.selected.slice();
    const request = ++overlayRequest;  // two quick picks: only the newest selection is drawn, whatever answers last
    $("overlay-ids").textContent = ids.length ? ids.join(" vs ") : t("fleet.select_two");
    let loops = [];
    try { loops = await Promise.all(ids.map((id) => api(`/api/tests/${encodeURIComponent(id)}/loop?max_points=3000`).then((a) => a.data))); }
    catch (e) { if (request === overlayRequest) message(e.message, true); return; }
    if (request !== overlayRequest) return;
    if (overlayPlot) { overlayPlot.destroy(); overlayPlot = null; }
    if (!loops.length) return;
    const label = (l) => { const r = state.runs.get(l.id) || { request: {} }; return `${l.id} · ${r.bench_id || ""} · ${r.request.serial_number || ""}`; };
    overlayPlot = new uPlot({
      mode: 2, width: width($("plot-overlay")), height: 380,
      scales: { x: { time: false, auto: true }, y: { auto: true } },
      axes: [{ label: t("dash.axis_torque") }, { label: t("dash.axis_loop_angle"), size: 70 }],
      series: [{}, ...loops.map((l, i) => ({ label: label(l), stroke: COLORS[i], width: 1.2, paths: uPlot.paths.linear(),
        points: { show: false }, facets: [{ scale: "x", auto: true }, { scale: "y", auto: true }] }))],
      legend: { show: true, live: false }, cursor: { show: false },
    }, [null, ...loops.map((l) => [l.torque_nm, l.angle_arcsec])], $("plot-overlay"));
  }

  // ---- SPC ----
  let spcPlot = null, mrPlot = null;
  function line(n, v) { return Array.from({ length: n }, () => v); }
  // a series is one test method: one position, the worst of N positions, the worst of N loading rates
  function methodLabel(m) {
    const [kind, n] = m.split("-");
    return kind === "positions" ? t("fleet.worst_positions", { n }) : kind === "rates" ? t("fleet.worst_rates", { n })
      : t("fleet.single");
  }
  function showMethods(methods, chosen) {
    const select = $("s-method");
    const keys = Array.from(new Set([chosen, ...Object.keys(methods)]));
    select.innerHTML = keys.map((m) => `<option value="${esc(m)}"${m === chosen ? " selected" : ""}>` +
      `${esc(methodLabel(m))} (${methods[m] || 0} runs)</option>`).join("");
  }
  $("spc-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const q = new URLSearchParams({ reducer: $("s-reducer").value.trim(), quantity: $("s-quantity").value,
      method: $("s-method").value || "single" });
    if ($("s-bench").value.trim()) q.set("bench", $("s-bench").value.trim());
    if ($("s-baseline").value) q.set("baseline_runs", $("s-baseline").value);
    let chart;
    try { chart = (await api("/api/spc/chart?" + q)).data; } catch (e) { $("spc-summary").textContent = e.message; return; }
    showMethods(chart.methods, chart.method);
    if (spcPlot) { spcPlot.destroy(); spcPlot = null; }
    if (mrPlot) { mrPlot.destroy(); mrPlot = null; }
    const where = chart.bench ? t("fleet.spc_on", { bench: chart.bench }) : t("fleet.spc_fleet");
    const runsOf = (n) => t("fleet.spc_runs", { n, reducer: chart.reducer, method: methodLabel(chart.method) });
    if (!chart.chart) {  // too few runs: no limits, say so
      $("spc-summary").textContent = `${runsOf(chart.runs.length)}${where}: ${chart.note}`;
      $("bias").tBodies[0].innerHTML = `<tr><td colspan="5" class="muted">–</td></tr>`;
      return;
    }
    const c = chart.chart, n = c.values.length, x = Array.from({ length: n }, (_, i) => i + 1);
    const flagged = c.values.map((v, i) => (c.flags[i].length ? v : null));
    $("spc-summary").textContent = `${runsOf(n)}${where}; ` +
      `${chart.note}: ${t("fleet.spc_centre")} ${c.center.toPrecision(5)}, σ̂ ${c.sigma.toPrecision(3)} ${chart.unit}; ` +
      `${t("fleet.spc_out")}: ${c.out_of_control.length ? c.out_of_control.map((i) => chart.runs[i].id).join(", ") : t("fleet.spc_none")}`;
    spcPlot = new uPlot({
      width: width($("plot-spc")), height: 240, scales: { x: { time: false } },
      axes: [{ label: t("fleet.spc_order") }, { label: chart.unit, size: 70 }],
      series: [{ label: t("fleet.spc_run") }, { label: t("fleet.spc_value"), stroke: "#1f5fa8", width: 1, points: { show: true, size: 4 } },
        { label: t("fleet.spc_centre"), stroke: "#157a2e", dash: [4, 4], points: { show: false } },
        { label: "UCL", stroke: "#b3261e", dash: [6, 3], points: { show: false } },
        { label: "LCL", stroke: "#b3261e", dash: [6, 3], points: { show: false } },
        { label: t("fleet.spc_out"), stroke: "transparent", points: { show: true, size: 9, stroke: "#b3261e", fill: "#b3261e" } }],
    }, [x, c.values, line(n, c.center), line(n, c.ucl), line(n, c.lcl), flagged], $("plot-spc"));
    mrPlot = new uPlot({
      width: width($("plot-mr")), height: 140, scales: { x: { time: false } },
      axes: [{}, { label: t("fleet.spc_mr"), size: 70 }],
      series: [{}, { label: "MR", stroke: "#5b6678", width: 1 },
        { label: "MR̄", stroke: "#157a2e", dash: [4, 4], points: { show: false } },
        { label: "UCL", stroke: "#b3261e", dash: [6, 3], points: { show: false } }],
    }, [x, c.moving_range, line(n, c.mr_center), line(n, c.mr_ucl)], $("plot-mr"));
    const b = new URLSearchParams({ reducer: chart.reducer, quantity: chart.quantity, method: chart.method });
    if ($("s-reference").value.trim()) b.set("reference", $("s-reference").value.trim());
    const body = $("bias").tBodies[0];
    try {
      const bias = (await api("/api/spc/bias?" + b)).data;
      body.innerHTML = bias.benches.map((r) => `<tr><td>${esc(r.bench)}${bias.reference === r.bench ? " (" + esc(t("fleet.spc_reference")) + ")" : ""}</td>` +
        `<td>${r.bias.toFixed(3)} ${esc(bias.unit)}</td><td>± ${r.U.toPrecision(2)} (k = ${r.k.toFixed(2)})</td>` +
        `<td>${r.runs}</td><td>${r.units}</td></tr>`).join("");
    } catch (e) { body.innerHTML = `<tr><td colspan="5" class="muted">${esc(e.message)}</td></tr>`; }
  });

  // ---- the audit trail (GET /api/audit: a signed-in user's or a token's; read only) ----
  // an action's or a role's words (the code itself when the catalogue does not know it)
  function word(kind, code) { const key = kind + "." + code, text = t(key); return text === key ? code : text; }
  async function loadAudit() {
    const body = $("audit").tBodies[0];
    let entries;
    try { entries = (await api("/api/audit?limit=50")).data; }
    catch (e) { body.innerHTML = `<tr><td colspan="7" class="muted">${esc(t("fleet.audit_needs_sign_in"))}</td></tr>`; return; }
    body.innerHTML = entries.map((e) => `<tr><td>${esc((e.at || "").replace("T", " ").slice(0, 19))}</td>` +
      `<td>${esc(e.user)}${e.role ? ` <span class="muted">${esc(word("role", e.role))}</span>` : ""}</td>` +
      `<td title="${esc(e.action)}">${esc(word("action", e.action))}</td>` +
      `<td>${esc(e.target || "—")}</td><td class="wrap">${esc(e.before || "—")}</td><td class="wrap">${esc(e.after || "—")}</td>` +
      `<td>${esc(e.bench_id || "—")}</td></tr>`).join("") || `<tr><td colspan="7" class="muted">–</td></tr>`;
  }

  // ---- discrepancy of any stored run: a button on each run, the result in words and the analyses' history ----
  async function discrepancyOf(id, button) {
    const out = $("discrepancy-result");
    button.disabled = true;
    out.textContent = t("dash.analysing", { id });
    try {
      const d = await TcmsDiscrepancy.start(id);
      out.textContent = t("disc.of_run", { id, text: TcmsDiscrepancy.describe(d) + " " +
        t("dash.against_model", { version: d.model_version }) });
    } catch (e) {
      out.textContent = t("disc.of_run", { id, text: e.message });
    } finally {
      button.disabled = false;
      TcmsDiscrepancy.history($("discrepancy-history").tBodies[0]);
    }
  }

  function addDiscrepancyButtons() {
    for (const tr of $("runs").tBodies[0].rows) {
      const id = tr.dataset.id;
      const cell = tr.querySelector("td.files");
      if (!id || !cell || cell.querySelector(".find-effects")) continue;
      cell.appendChild(TcmsDiscrepancy.findEffectsButton(id, discrepancyOf));
    }
  }
  new MutationObserver(addDiscrepancyButtons).observe($("runs").tBodies[0], { childList: true });
  TcmsDiscrepancy.history($("discrepancy-history").tBodies[0]);

  window.tcmsFleet = { state };
  search();
  loadAudit();
})();
