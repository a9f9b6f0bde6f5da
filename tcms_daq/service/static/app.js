// TCMS-DAQ dashboard: live binary frames -> ring of typed-array chunks -> uPlot.setData once per animation frame.
// Frame layout (little-endian): "TCMS", u16 version, u16 n_channels, u64 sequence, f64 t0_s, u32 n_samples,
// u32 dropped, then n_channels float32 columns (time_s - t0_s, torque_nm, encoder_arcsec, angle_arcsec).
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const HEADER_SIZE = 32;
  const WINDOW_S = 10;          // visible history of the time traces (acquisition clock seconds)
  // The loop is decimated by stride doubling to stay below this: uPlot's own per-pixel decimation (above 4 points
  // per pixel) assumes x increases monotonically, which a hysteresis loop (x = torque) does not.
  const LOOP_MAX_POINTS = 1000;

  const state = {
    frames: 0, dropped: 0, lastSeq: 0, gaps: 0,
    chunks: [],                 // {t: Float64Array, torque, encoder, angle: Float32Array}
    loop: { x: [], y: [], stride: 1, counter: 0 },
    activeId: null, testState: "idle", eventSeq: 0, dirty: false, schema: null, resultId: null,
    method: "stiffness",        // the active (or shown) test's method
    clockSpeed: 1,              // simulated clock seconds per real second (GET /api/bench sim_speed)
  };

  // ---- words (i18n.js), the API token and requests (session.js) ----
  const { t } = TcmsI18n;
  TcmsI18n.apply(document);
  TcmsI18n.bindSwitch($("lang"));
  const { withToken, escapeHtml } = TcmsSession;
  const { roundToU, fmt3 } = TcmsRounding;
  const link = (path) => withToken(TcmsI18n.withLang(path));
  TcmsSession.bindTokenField($("f-token"), () => whoAmI());

  function message(text, isError) {
    $("message").textContent = text || "";
    $("message").className = isError ? "error" : "";
  }

  async function api(method, path, body) { return (await TcmsSession.request(method, path, body)).data; }

  // ---- plots ----
  function width(el) { return Math.max(300, el.clientWidth - 4); }
  // At idle the traces are sensor noise: a y axis of at least this span (centred on the data) shows a flat line,
  // not the noise blown up into a band; a test's excursion is far larger and sets its own span.
  const MIN_SPAN = { torque: 20, angle: 20 };  // N·m, arcsec
  function spanAtLeast(span) {
    return (u, lo, hi) => {
      if (lo == null || hi == null || !isFinite(lo) || !isFinite(hi)) return [-span / 2, span / 2];
      const mid = (lo + hi) / 2, half = Math.max((hi - lo) * 0.55, span / 2);
      return [mid - half, mid + half];
    };
  }

  const torquePlot = new uPlot({
    width: width($("plot-torque")), height: 200,
    scales: { x: { time: false }, y: { range: spanAtLeast(MIN_SPAN.torque) } },
    axes: [{ label: t("dash.axis_time") }, { label: t("dash.axis_torque"), size: TcmsMethodView.axisSize }],
    series: [{ label: "t / s" }, { label: t("dash.axis_torque"), stroke: "#1f5fa8", width: 1 }],
    legend: { live: false },
  }, [[], []], $("plot-torque"));

  const anglePlot = new uPlot({
    width: width($("plot-angle")), height: 200,
    scales: { x: { time: false }, y: { range: spanAtLeast(MIN_SPAN.angle) } },
    axes: [{ label: t("dash.axis_time") }, { label: t("dash.axis_angle"), size: TcmsMethodView.axisSize }],
    series: [
      { label: "t / s" },
      { label: t("dash.raw_encoder"), stroke: "#b8c0cc", width: 1 },
      { label: t("dash.compensated"), stroke: "#d9771e", width: 1 },
    ],
    legend: { live: false },
  }, [[], [], []], $("plot-angle"));

  const loopPlot = new uPlot({
    mode: 2,
    width: width($("plot-loop")), height: 330,
    scales: { x: { time: false, auto: true }, y: { auto: true } },
    axes: [{ label: t("dash.axis_torque") }, { label: t("dash.axis_loop_angle"), size: TcmsMethodView.axisSize }],
    series: [
      {},
      { label: "hysteresis loop", stroke: "#157a2e", width: 1.5, paths: uPlot.paths.linear(), points: { show: false },
        facets: [{ scale: "x", auto: true }, { scale: "y", auto: true }] },
    ],
    legend: { show: false },
    cursor: { show: false },
  }, [null, [[], []]], $("plot-loop"));

  window.addEventListener("resize", () => {
    torquePlot.setSize({ width: width($("plot-torque")), height: 200 });
    anglePlot.setSize({ width: width($("plot-angle")), height: 200 });
    loopPlot.setSize({ width: width($("plot-loop")), height: 330 });
  });

  // ---- live stream ----
  function parseFrame(buf) {
    const dv = new DataView(buf);
    const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
    if (magic !== "TCMS") throw new Error("not a TCMS frame");
    const nch = dv.getUint16(6, true);
    const seq = Number(dv.getBigUint64(8, true));
    const t0 = dv.getFloat64(16, true);
    const n = dv.getUint32(24, true);
    const dropped = dv.getUint32(28, true);
    const cols = [];
    for (let c = 0; c < nch; c++) cols.push(new Float32Array(buf, HEADER_SIZE + 4 * n * c, n));
    return { seq, t0, n, dropped, cols };
  }

  function addToLoop(torque, angle) {
    if (state.outputMoving) return;  // the output turning to the next position is no part of a loop
    if (state.method !== "stiffness") return;  // a turning test draws its own view (method_view.js)
    const loop = state.loop;
    for (let i = 0; i < torque.length; i++) {
      if (loop.counter++ % loop.stride !== 0) continue;
      loop.x.push(torque[i]);
      loop.y.push(angle[i]);
    }
    if (loop.x.length > LOOP_MAX_POINTS) {
      loop.x = loop.x.filter((_, i) => i % 2 === 0);
      loop.y = loop.y.filter((_, i) => i % 2 === 0);
      loop.stride *= 2;
    }
  }

  function onFrame(f) {
    if (state.lastSeq && f.seq !== state.lastSeq + 1) state.gaps += 1;
    state.lastSeq = f.seq;
    state.frames += 1;
    state.dropped = f.dropped;
    const t = new Float64Array(f.n);
    for (let i = 0; i < f.n; i++) t[i] = f.t0 + f.cols[0][i];
    const chunk = { t, torque: f.cols[1], encoder: f.cols[2], angle: f.cols[3] };
    state.chunks.push(chunk);
    const newest = t.length ? t[t.length - 1] : 0;
    while (state.chunks.length > 1) {
      const first = state.chunks[0].t;
      if (first.length && first[first.length - 1] < newest - WINDOW_S) state.chunks.shift(); else break;
    }
    if (state.testState === "running" && f.n) addToLoop(chunk.torque, chunk.angle);
    state.dirty = true;
  }

  function concat(key) {
    let n = 0;
    for (const c of state.chunks) n += c[key].length;
    const out = new Float64Array(n);
    let o = 0;
    for (const c of state.chunks) { out.set(c[key], o); o += c[key].length; }
    return out;
  }

  function paint() {
    if (state.dirty) {
      state.dirty = false;
      const t = concat("t");
      torquePlot.setData([t, concat("torque")]);
      anglePlot.setData([t, concat("encoder"), concat("angle")]);
      loopPlot.setData([null, [state.loop.x, state.loop.y]]);
      $("loop-points").textContent = state.loop.x.length;
      $("live-frames").textContent = state.frames;
      $("live-dropped").textContent = state.dropped;
      showReadouts();
    }
    requestAnimationFrame(paint);
  }
  requestAnimationFrame(paint);

  // the large readouts: the newest samples of the live stream (their mean over 20 ms, so the last digit is not
  // the sensor's noise), torque to 0.1 N·m and angle to 0.1″: the live view, not a result
  function newest(key, n) {
    const last = state.chunks[state.chunks.length - 1];
    if (!last || !last[key].length) return null;
    const col = last[key], from = Math.max(0, col.length - n);
    let sum = 0, count = 0;
    for (let i = from; i < col.length; i++) if (isFinite(col[i])) { sum += col[i]; count++; }
    return count ? sum / count : null;
  }
  function showReadouts() {
    const n = Math.max(1, Math.round(((state.schema && state.schema.rate_hz) || 1000) * 0.02));
    const torque = newest("torque", n), angle = newest("angle", n);
    $("ro-torque").textContent = torque === null ? "–" : (Math.abs(torque) < 0.05 ? 0 : torque).toFixed(1);
    // an output turned to another position reads in degrees (648000″ is 180°), near zero in arcseconds
    const degrees = angle !== null && Math.abs(angle) >= 3600;
    $("ro-angle").textContent = angle === null ? "–" : degrees ? (angle / 3600).toFixed(4) : angle.toFixed(1);
    $("ro-angle-unit").textContent = degrees ? "°" : "″";
  }

  function wsUrl(path) {
    return (location.protocol === "https:" ? "wss://" : "ws://") + location.host + withToken(path);
  }

  function connectLive() {
    const ws = new WebSocket(wsUrl("/ws/live"));
    ws.binaryType = "arraybuffer";
    ws.onopen = () => { $("live-state").textContent = t("dash.connected"); };
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") { state.schema = JSON.parse(ev.data); state.lastSeq = 0; return; }
      onFrame(parseFrame(ev.data));
    };
    ws.onclose = () => { $("live-state").textContent = t("dash.reconnecting"); setTimeout(connectLive, 1000); };
  }
  connectLive();

  // ---- test state over the lossless event channel ----
  function setTestState(id, status) {
    if (id) { state.activeId = id; $("test-id").textContent = id; }
    state.testState = status;
    $("test-state").textContent = t("state." + status);
    $("ro-state").textContent = t("state." + status);
    $("ro-state").dataset.state = status;
    const active = status === "queued" || status === "running";
    $("start").disabled = active;
    $("abort").disabled = !active;
    if (!active) { $("ro-eta").textContent = "–"; $("ro-eta-unit").textContent = ""; $("ro-phase").textContent = ""; }
  }

  function connectEvents() {
    const ws = new WebSocket(wsUrl("/ws/events" + (state.eventSeq ? "?since=" + state.eventSeq : "")));
    ws.onopen = () => { $("events-state").textContent = t("dash.connected"); };
    ws.onmessage = (ev) => {
      const e = JSON.parse(ev.data);
      if (e.type === "hello") { if (!state.eventSeq) syncBench(); return; }
      state.eventSeq = e.seq;
      if (e.type === "test_state") {
        if (e.status === "queued" && e.id !== state.activeId) { resetLoop(); startMethod((e.request || {}).method); }
        setTestState(e.id, e.status);
        if (["completed", "aborted", "failed", "interrupted"].includes(e.status)) {
          $("test-phase").textContent = "–";
          $("ro-phase").textContent = "";
          $("progress").hidden = true;
          state.outputMoving = false;
          $("progress-text").textContent = "";
          showResults(e.id);
          loadHistory();
          if (e.error) message(t("state." + e.status) + ": " + e.error, e.status !== "aborted");
          else message(t("dash.test_ended", { status: t("state." + e.status) }));
        }
      } else if (e.type === "test_phase") {
        $("test-phase").textContent = e.phase;
        $("ro-phase").textContent = e.phase;
      } else if (e.type === "test_progress") {
        showProgress(e);
      } else if (e.type === "method_progress") {
        showMethodProgress(e);
      } else if (e.type === "te_live") {
        if (e.id === state.activeId) TcmsMethodView.onTeLive(e);
      }
    };
    ws.onclose = () => { $("events-state").textContent = t("dash.reconnecting"); setTimeout(connectEvents, 1000); };
  }

  // progress of the active test (test_progress events): the bar is the elapsed share of elapsed + ETA; times in
  // real seconds (clock seconds divided by the simulated clock's speed)
  function duration(s) {
    s = Math.max(0, Math.round(s));
    const [h, m, sec] = [t("dash.hours"), t("dash.minutes"), t("dash.seconds")];
    return s >= 3600 ? Math.floor(s / 3600) + " " + h + " " + Math.floor((s % 3600) / 60) + " " + m
      : s >= 60 ? Math.floor(s / 60) + " " + m + " " + (s % 60) + " " + sec : s + " " + sec;
  }
  function showProgress(e) {
    // the output turns to the next position: no loop points meanwhile; the new position's loops (degrees away
    // from the last one's) start a new plot
    if (e.moving) state.outputMoving = true;
    else if (state.outputMoving) { state.outputMoving = false; resetLoop(); }
    const speed = e.clock_speed > 0 ? e.clock_speed : 1;
    const done = e.elapsed_s / speed, left = e.eta_s / speed;
    const share = done + left > 0 ? done / (done + left) : 0;
    $("progress").hidden = false;
    $("progress-bar").style.width = (100 * share).toFixed(1) + "%";
    const parts = [];
    if (e.positions > 1) parts.push(t("prog.position", { n: e.position, of: e.positions }) + (e.position_deg != null ? " (" + fmt(e.position_deg) + "°)" : ""));
    else if (e.stages > 1) parts.push(t("prog.rate", { n: e.stage, of: e.stages }) + (e.rate_nm_per_s != null ? " (" + fmt(e.rate_nm_per_s) + " N·m/s)" : ""));
    parts.push(e.moving ? t("prog.moving") : e.loop === 0 ? t("prog.conditioning") : e.loop > 0 ? t("prog.loop", { n: e.loop, of: e.loops }) : t("prog.approach"));
    parts.push(t("prog.elapsed", { time: duration(done) }), t("prog.eta", { time: duration(left) }));
    $("progress-text").textContent = parts.join(" · ");
    // the readout: real seconds left (the clock's seconds divided by a simulated clock's speed)
    const secondsLeft = Math.max(0, Math.round(left));
    $("ro-eta").textContent = secondsLeft >= 60 ? Math.floor(secondsLeft / 60) + ":" + String(secondsLeft % 60).padStart(2, "0") : String(secondsLeft);
    $("ro-eta-unit").textContent = secondsLeft >= 60 ? t("dash.minutes") + ":" + t("dash.seconds") : t("dash.seconds");
  }

  // a turning test's method or the stiffness test: what the view shows while it runs
  function startMethod(method) {
    state.method = method || "stiffness";
    TcmsMethodView.show(state.method);
    if (state.method === "transmission-error") TcmsMethodView.startLive();
  }

  // a step of a turning test's procedure in words ("1208 rpm forward", "forward 2/3", "load" …)
  function stepName(name) {
    const dir = (d) => t("certificate.direction_" + d);
    let m = /^(\S+) rpm (forward|reverse)$/.exec(name || "");
    if (m) return t("step.speed", { speed: m[1], direction: dir(m[2]) });
    m = /^(forward|reverse) (\d+)\/(\d+)$/.exec(name || "");
    if (m) return t("step.creep", { direction: dir(m[1]), n: m[2], of: m[3] });
    return ["forward", "reverse"].includes(name) ? dir(name) : t("step." + name) === "step." + name ? String(name) : t("step." + name);
  }
  // progress of a turning test (method_progress events: clock seconds, turned into real ones by the clock's speed)
  function showMethodProgress(e) {
    const speed = state.clockSpeed > 0 ? state.clockSpeed : 1;
    const done = e.elapsed_s / speed, left = e.eta_s / speed;
    $("progress").hidden = false;
    $("progress-bar").style.width = (100 * (done + left > 0 ? done / (done + left) : 0)).toFixed(1) + "%";
    const step = Math.min(e.step + 1, e.steps);
    $("progress-text").textContent = [t("prog.step", { n: step, of: e.steps }) + ": " + stepName(e.step_name),
      t("prog.elapsed", { time: duration(done) }), t("prog.eta", { time: duration(left) })].join(" · ");
    $("test-phase").textContent = stepName(e.step_name);
    $("ro-phase").textContent = stepName(e.step_name);
    const secondsLeft = Math.max(0, Math.round(left));
    $("ro-eta").textContent = secondsLeft >= 60 ? Math.floor(secondsLeft / 60) + ":" + String(secondsLeft % 60).padStart(2, "0") : String(secondsLeft);
    $("ro-eta-unit").textContent = secondsLeft >= 60 ? t("dash.minutes") + ":" + t("dash.seconds") : t("dash.seconds");
  }

  // per-position / per-rate table of a test of several stages, and its summary (max, min, spread)
  function showStages(res) {
    const table = $("stages");
    const entries = res.positions || res.rates;
    if (!entries || !entries.length) { table.hidden = true; return; }
    const positional = !!res.positions;
    const KEYS = ["rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec"];
    // each value to the decimal place of its U; the summary rows to that of the largest U of their column
    const largestU = {};
    for (const k of KEYS) {
      const us = entries.map((e) => e.uncertainty && e.uncertainty[k] && e.uncertainty[k].U).filter((u) => typeof u === "number" && u > 0);
      largestU[k] = us.length ? Math.max(...us) : null;
    }
    const cell = (e, k) => {
      const u = e.uncertainty && e.uncertainty[k];
      if (typeof e[k] !== "number") return "–";
      if (!u || !(u.U > 0)) return fmt3(e[k]);
      const [v, r] = roundToU(e[k], u.U);
      return v + " ± " + r;
    };
    const summary = (k, v) => typeof v !== "number" ? "–" : largestU[k] ? roundToU(v, largestU[k])[0] : fmt3(v);
    table.tHead.innerHTML = "<tr><th>" + escapeHtml(positional ? t("res.position") : t("res.rate")) + "</th>" +
      ["res.rigidity_short", "res.lost_motion_short", "res.backlash_short"].map((k) => "<th>" + escapeHtml(t(k)) + "</th>").join("") + "</tr>";
    const rows = entries.map((e) => [positional ? fmt(e.position_deg) : fmt(e.rate_nm_per_s),
      cell(e, "rigidity_nm_per_arcmin"), cell(e, "lost_motion_arcsec"), cell(e, "backlash_arcsec")]);
    for (const stat of ["max", "min", "spread"]) {
      rows.push([t("res." + stat), ...KEYS.map((k) => summary(k, res[k + "_" + stat]))]);
    }
    const sens = res.rate_sensitivity;
    if (sens) rows.push([t("res.per_decade"), ...KEYS.map((k) =>
      typeof sens[k + "_per_decade"] === "number" ? fmt2(sens[k + "_per_decade"]) : "–")]);
    table.tBodies[0].innerHTML = rows.map((r) => "<tr>" + r.map((c, i) => (i ? "<td>" : "<th>") + escapeHtml(String(c)) + (i ? "</td>" : "</th>")).join("") + "</tr>").join("");
    table.hidden = false;
  }

  function resetLoop() { state.loop = { x: [], y: [], stride: 1, counter: 0 }; state.dirty = true; }

  function fmt(v) { return typeof v === "number" ? (Math.abs(v) >= 1e5 || (v !== 0 && Math.abs(v) < 1e-3) ? v.toExponential(4) : +v.toPrecision(6)) : String(v); }
  function verdictClass(v) {
    if (v === true || v === "pass" || v === "passed") return "pass";
    if (v === false || v === "fail" || v === "failed") return "fail";
    return "";
  }

  // A result as "value ± U (k = …)" (rounding.js: the one rounding of the pages)
  function fmtU(value, entry) { return TcmsRounding.withU(value, entry && entry.U, entry && entry.k); }
  // a spread shown with two significant digits, not "0.0708006"
  function fmt2(v) { return typeof v === "number" ? (v === 0 ? "0" : +v.toPrecision(2) + "") : "–"; }

  // Results: the headline quantities (value ± U, the dominant contributor, the std over the evaluated loops),
  // the verdict checks with their ISO 14253-1 decision, the warnings; results of an unknown shape fall back to
  // their top-level scalars.
  const HEADLINE = [
    ["rigidity_nm_per_arcmin", t("res.rigidity"), true],
    ["lost_motion_arcsec", t("res.lost_motion"), true],
    ["backlash_arcsec", t("res.backlash"), true],
    ["loading_rate_nm_per_s", t("res.loading_rate"), false],
    ["test_torque_nm", t("res.test_torque"), false],
    ["n_loops", t("res.n_loops"), false],
  ];
  const DECISION_WORD = { pass: t("res.pass"), fail: t("res.fail"), undecided: t("res.undecided") };
  // a check's requirement in this page's language ("扭转刚度 ≥ 235.2 N·m/arcmin"); the service's own label else
  const QUANTITY = { rigidity_nm_per_arcmin: ["res.rigidity", "N·m/arcmin"], lost_motion_arcsec: ["res.lost_motion", "″"],
    backlash_arcsec: ["res.backlash", "″"] };
  function checkLabel(c) {
    const q = QUANTITY[c.quantity];
    const op = { ">=": "≥", "<=": "≤", ">": ">", "<": "<" }[c.comparison];
    if (TcmsI18n.lang === "en" || !q || !op || typeof c.limit !== "number") return c.label || `${c.quantity} ${c.comparison} ${fmt(c.limit)}`;
    return `${t(q[0]).split(" / ")[0]} ${op} ${fmt(c.limit)}${q[1] === "″" ? "″" : " " + q[1]}`;
  }
  function decisionOf(c) { return c.decision || (c.passed ? "pass" : "fail"); }

  function resultRows(res) {
    const rows = [];
    const std = res.std || {};
    const unc = res.uncertainty || {};
    for (const [key, label, uncertain] of HEADLINE) {
      if (typeof res[key] !== "number") continue;
      if (uncertain) {
        const entry = unc[key];
        const notes = [];
        if (entry && entry.dominant) notes.push(t("res.dominant", { name: TcmsI18n.source(entry.dominant) }));
        if (typeof std[key] === "number") notes.push(t("res.std", { value: fmt2(std[key]) }));
        rows.push([label, fmtU(res[key], entry), "", notes.join(" · ")]);
      } else {
        rows.push([label, fmt3(res[key]), ""]);
      }
    }
    for (const k of ["k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad"]) {
      if (typeof res[k] === "number") rows.push([k.slice(0, 2).toUpperCase() + " / N·m/rad", fmtU(res[k], unc[k]), ""]);
    }
    if (res.uncertainty_basis) rows.push([t("res.u_basis"), TcmsI18n.source(res.uncertainty_basis), "muted"]);
    const verdict = res.verdict;
    if (verdict && typeof verdict === "object") {
      for (const [name, c] of Object.entries(verdict.checks || {})) {
        const d = decisionOf(c);
        const guard = typeof c.guard_band === "number" && c.guard_band > 0 ? ", " + t("res.guard_band", { value: fmt2(c.guard_band) }) : "";
        rows.push([checkLabel(c), DECISION_WORD[d] + " (" + fmt3(c.value) + guard + ")", d]);
      }
      const d = decisionOf(verdict);
      // the decision first: it is what the operator looks for
      rows.unshift([t("res.decision"), DECISION_WORD[d] + (verdict.rule ? " (" + t("res.rule", { rule: TcmsI18n.rule(verdict.rule) }) + ")" : ""), d,
                    TcmsI18n.reasons(verdict).join(" · ")]);
    }
    for (const w of TcmsI18n.warnings(res)) rows.push([t("res.warning"), w, "warning"]);
    if (!rows.length) {
      for (const [k, v] of Object.entries(res)) {
        if (v === null || typeof v === "object") continue;
        rows.push([k, v === true ? "pass" : v === false ? "FAIL" : fmt(v), verdictClass(v)]);
      }
    }
    return rows;
  }

  // a turning test's results (docs/transmission.md): each quantity of GET /api/tests/{id}/curves as value ± U (k)
  // with its dominant contributor; the efficiency in %; the transmission error's lost motion under the light load
  const UNIT_SHOWN = { arcsec: "″", "N·m": "N·m", "1": "%" };
  function methodRows(res, curves) {
    const rows = [];
    const unc = res.uncertainty || {};
    for (const q of curves.quantities || []) {
      const entry = unc[q.key];
      const scale = q.unit === "1" ? 100 : 1;
      const label = t("certificate.q_" + q.label, { speed: q.speed_rpm === null ? "" : fmt(q.speed_rpm) }) + " / " + (UNIT_SHOWN[q.unit] || q.unit);
      const value = typeof res[q.key] === "number" ? scale * res[q.key] : null;
      const shown = TcmsRounding.withU(value, entry && scale * entry.U, entry && entry.k);
      rows.push([label, shown, "", entry && entry.dominant ? t("res.dominant", { name: TcmsI18n.source(entry.dominant) }) : ""]);
    }
    if (typeof res.hysteresis_arcsec === "number") rows.push([t("certificate.q_hysteresis_arcsec") + " / ″", fmt3(res.hysteresis_arcsec), ""]);
    if (res.uncertainty_basis) rows.push([t("res.u_basis"), TcmsI18n.source(res.uncertainty_basis), "muted"]);
    for (const w of TcmsI18n.warnings(res)) rows.push([t("res.warning"), w, "warning"]);
    return rows;
  }

  async function showResults(id) {
    let run;
    try { run = await api("GET", "/api/tests/" + encodeURIComponent(id)); } catch (e) { return; }
    const method = (run.results && run.results.method) || run.request.method || "stiffness";
    let curves = null;
    if (method !== "stiffness" && run.results) {
      try { curves = await api("GET", "/api/tests/" + encodeURIComponent(id) + "/curves"); } catch (e) { curves = null; }
    }
    const body = $("results").tBodies[0];
    body.innerHTML = "";
    const rows = !run.results ? [] : curves ? methodRows(run.results, curves) : resultRows(run.results);
    if (!["queued", "running"].includes(run.status) || id !== state.activeId) {
      state.method = method;
      if (curves) TcmsMethodView.showStored(curves); else TcmsMethodView.show(method);
    }
    showStages(run.results || {});
    if (!rows.length) {
      body.innerHTML = `<tr><td class="muted">${escapeHtml(t("state." + run.status))}${run.error ? ": " + escapeHtml(run.error) : ""}</td></tr>`;
    }
    for (const [label, value, cls, note] of rows) {
      const tr = document.createElement("tr");
      tr.innerHTML = `<th>${escapeHtml(label)}</th><td class="${cls}">${escapeHtml(String(value))}` +
        (note ? `<div class="note">${escapeHtml(note)}</div>` : "") + `</td>`;
      body.appendChild(tr);
    }
    const report = $("report-link");
    report.href = link("/api/tests/" + encodeURIComponent(id) + "/report");
    report.hidden = false;
    state.resultId = id;
    // a page opened after the test draws the test's loop from the store
    if (method === "stiffness" && !state.loop.x.length && run.sample_count > 0 && !["queued", "running"].includes(run.status)) {
      try {
        const loop = await api("GET", "/api/tests/" + encodeURIComponent(id) + "/loop?max_points=" + LOOP_MAX_POINTS);
        if (!state.loop.x.length) { state.loop = { x: loop.torque_nm, y: loop.angle_arcsec, stride: 1, counter: 0 }; state.dirty = true; }
      } catch (e) { /* the live loop stays empty */ }
    }
    // the stiffness test's model discrepancy (a turning test's transmission error has its own workflow)
    $("discrepancy").disabled = method !== "stiffness" || !(run.sample_count > 0) || ["queued", "running"].includes(run.status);
    $("discrepancy-link").hidden = true;
    $("discrepancy-result").textContent = "";
    $("apply-effects").hidden = true;
    state.analysis = null;
  }

  // ---- discrepancy: the shown run against the bench model (POST /api/discrepancy) ----
  const describeDiscrepancy = (d) => TcmsDiscrepancy.describe(d);

  // ---- the bench model: its version, and "apply" after an analysis that named something ----
  async function loadModel() {
    try {
      const m = await api("GET", "/api/model");
      $("model-version").textContent = "v" + m.version;
      $("model-version").title = m.terms.length
        ? t("dash.model_effects", { names: m.terms.map((term) => term.name).join(", ") }) : t("dash.model_alone");
    } catch (e) { /* shown as it was */ }
  }

  $("apply-effects").addEventListener("click", async () => {
    const d = state.analysis;
    if (!d) return;
    let body = {};
    if (d.names_provisional) {
      if (!window.confirm(t("dash.confirm_provisional"))) return;
      body = { accept_provisional: true };
    }
    $("apply-effects").disabled = true;
    try {
      const m = await api("POST", "/api/discrepancy/" + d.id + "/apply", body);
      message(t("dash.model_saved", { version: m.version, note: m.history[0].note }));
      $("apply-effects").hidden = true;
      await loadModel();
    } catch (e) {
      message(t("dash.apply_error", { error: e.message }), true);
      $("apply-effects").disabled = false;
    }
  });

  $("discrepancy").addEventListener("click", () => analyseShownRun());

  async function analyseShownRun() {
    const id = state.resultId;
    if (!id) return;
    $("discrepancy").disabled = true;
    $("apply-effects").hidden = true;
    $("discrepancy-result").textContent = t("dash.analysing", { id });
    TcmsDiscrepancy.offerRuns($("discrepancy-result"), null);
    try {
      const d = await api("POST", "/api/discrepancy", { run_id: id });
      state.analysis = d;
      $("discrepancy-result").textContent = describeDiscrepancy(d) + " " + t("dash.against_model", { version: d.model_version });
      TcmsDiscrepancy.offerRuns($("discrepancy-result"), d);
      const named = d.effects.length > 0 || d.aliases.some((a) => a.in_model);
      $("apply-effects").hidden = !named;
      $("apply-effects").disabled = !named;
      const link = $("discrepancy-link");
      link.href = withToken(d.report_url);
      link.hidden = false;
    } catch (e) {
      $("discrepancy-result").textContent = "";
      message("discrepancy: " + e.message, true);
    } finally {
      $("discrepancy").disabled = state.resultId !== id;
      loadDiscrepancyHistory();
    }
  }

  // ---- discrepancy of any stored run: a button on each recent test, and the analyses' history ----
  async function discrepancyOfStoredRun(id) {
    await showResults(id);
    if (state.resultId === id && !$("discrepancy").disabled) await analyseShownRun();
  }

  function addDiscrepancyButtons() {
    for (const tr of $("history").tBodies[0].rows) {
      const id = tr.title;  // the row names its run by time; the id is its title
      if (!id || tr.querySelector(".find-effects") || tr.dataset.method !== "stiffness") continue;  // the stiffness test's
      tr.cells[tr.cells.length - 1].appendChild(TcmsDiscrepancy.findEffectsButton(id, discrepancyOfStoredRun));
    }
  }
  new MutationObserver(addDiscrepancyButtons).observe($("history").tBodies[0], { childList: true });

  function loadDiscrepancyHistory() {
    return TcmsDiscrepancy.history($("discrepancy-history").tBodies[0]);
  }

  // this bench's own recent runs (a store several benches share lists every bench's on the fleet page)
  async function loadHistory() {
    let runs = [];
    const bench = state.benchId ? "&bench=" + encodeURIComponent(state.benchId) : "";
    try { runs = await api("GET", "/api/tests?limit=8" + bench); } catch (e) { return; }
    // a page opened after a test shows that test's results
    if (!state.resultId && runs.length && !["queued", "running"].includes(runs[0].status)) showResults(runs[0].id);
    const body = $("history").tBodies[0];
    body.innerHTML = "";
    for (const r of runs) {
      const tr = document.createElement("tr");
      const id = encodeURIComponent(r.id);
      tr.title = r.id;  // the run's time names it here; its id is on hover and in the report
      tr.dataset.method = r.request.method || "stiffness";
      tr.innerHTML = `<td>${escapeHtml((r.created_at || "").slice(5, 16).replace("T", " "))}</td><td>${escapeHtml(String(r.request.serial_number || "—"))}</td>` +
        `<td>${escapeHtml(t("state." + r.status))}</td>` +
        `<td class="${escapeHtml(r.verdict || "")}">${escapeHtml(r.verdict ? t("verdict." + r.verdict) : "—")}</td>` +
        `<td class="files"><a href="${escapeHtml(link("/api/tests/" + id + "/report"))}" target="_blank">${escapeHtml(t("dash.report"))}</a>` +
        `<a href="${escapeHtml(link("/api/tests/" + id + "/certificate.pdf"))}" target="_blank">${escapeHtml(t("dash.certificate"))}</a></td>`;
      body.appendChild(tr);
    }
  }

  async function syncBench() {
    try {
      const bench = await api("GET", "/api/bench");
      $("bench-name").textContent = bench.display_name || bench.name || "";
      if (bench.id && bench.id !== state.benchId) { state.benchId = bench.id; loadHistory(); }
      const sel = $("f-reducer");
      if (!sel.options.length) {
        for (const r of bench.reducers || []) {
          const o = document.createElement("option");
          o.value = r.name; o.textContent = `${r.name} (${r.rated_torque_nm} N·m)`;
          o.dataset.maxTorque = r.max_test_torque_nm;
          sel.appendChild(o);
        }
      }
      applyBounds(bench.test_bounds || {});
      state.clockSpeed = bench.clock === "simulated" && bench.sim_speed > 0 ? bench.sim_speed : 1;
      // each method this bench can run; one it cannot is shown, disabled, with what it needs
      for (const o of $("f-method").options) {
        const why = (bench.methods || {})[o.value];
        o.disabled = !!why;
        o.title = why || "";
      }
      if (bench.active_test) {
        const run = await api("GET", "/api/tests/" + encodeURIComponent(bench.active_test));
        setTestState(run.id, run.status);
      }
      $("live-rate").textContent = Math.round(bench.live.acquisition_rate_samples_per_second);
      if (bench.not_ready) message(bench.not_ready, true);  // the safe start left the bench unsafe: no test yet
    } catch (e) { message(t("dash.bench_status_error", { error: e.message }), true); }
  }
  // The form's limits are the service's own (GET /api/bench → test_bounds), so the browser refuses what the
  // API would refuse, with the bench's numbers.
  function applyBounds(b) {
    const set = (id, attr, v) => { if (v !== undefined && v !== null) $(id).setAttribute(attr, v); };
    set("f-rate", "min", b.min_rate_nm_per_s);
    set("f-rate", "max", b.max_rate_nm_per_s);
    set("f-step", "min", b.min_step_nm);
    set("f-torque", "max", b.max_torque_nm);
    state.bounds = b;
    reducerBound();
  }
  function reducerBound() {
    const o = $("f-reducer").selectedOptions[0];
    const bench = (state.bounds || {}).max_torque_nm;
    const limit = o && o.dataset.maxTorque ? parseFloat(o.dataset.maxTorque) : bench;
    if (limit !== undefined) $("f-torque").setAttribute("max", limit);
  }
  $("f-reducer").addEventListener("change", reducerBound);

  setInterval(async () => {
    try {
      const bench = await api("GET", "/api/bench");
      $("live-rate").textContent = Math.round(bench.live.acquisition_rate_samples_per_second);
    } catch (e) { /* service restarting */ }
  }, 2000);

  // ---- controls ----
  $("f-profile").addEventListener("change", () => {
    $("test-form").classList.toggle("stepped", $("f-profile").value === "stepped");
  });

  // the method picker: the form shows the method's own fields (index.html: .stiffness-only, .for-te …)
  function pickMethod() {
    $("test-form").dataset.method = $("f-method").value;
  }
  $("f-method").addEventListener("change", () => { clearInvalid(); pickMethod(); });
  // a turning test's request: the method and the parameters given (the others take the method's defaults)
  const METHOD_INPUTS = {
    "transmission-error": { input_speed_rpm: "f-input-speed", load_torque_nm: "f-load", revolutions: "f-revolutions" },
    "starting-torque": { ramps: "f-ramps", creep_deg_per_s: "f-creep" },
    "no-load-torque": { speeds_rpm: "f-speeds", dwell_s: "f-hold" },
    "efficiency": { input_speed_rpm: "f-input-speed", load_torque_nm: "f-load", dwell_s: "f-hold" },
  };
  function methodRequest(method) {
    const req = { reducer: $("f-reducer").value, method };
    for (const [key, id] of Object.entries(METHOD_INPUTS[method])) {
      const raw = $(id).value.trim();
      if (!raw) continue;
      req[key] = key === "speeds_rpm" ? raw.split(",").map(Number) : key === "ramps" ? parseInt(raw, 10) : parseFloat(raw);
    }
    return req;
  }

  // the form as a test request (POST /api/tests; a saved plan keeps the same body)
  function formRequest() {
    const method = $("f-method").value;
    if (method !== "stiffness") {
      const req = methodRequest(method);
      if ($("f-serial").value.trim()) req.serial_number = $("f-serial").value.trim();
      if ($("f-operator").value.trim()) req.operator = $("f-operator").value.trim();
      return req;
    }
    const req = {
      reducer: $("f-reducer").value,
      max_torque_nm: parseFloat($("f-torque").value),
      cycles: parseInt($("f-cycles").value, 10),
      profile: $("f-profile").value,
    };
    const rate = parseFloat($("f-rate").value);
    if (rate > 0) req.rate_nm_per_s = rate;
    if (req.profile === "stepped") {
      req.step_nm = parseFloat($("f-step").value);
      req.dwell_s = parseFloat($("f-dwell").value);
    }
    const positions = $("f-positions").value.trim();
    if (positions) req.positions = /^\d+$/.test(positions) ? parseInt(positions, 10) : positions.split(",").map(Number);
    const rates = $("f-rates").value.trim();
    if (rates) { req.rates = rates.split(",").map(Number); delete req.rate_nm_per_s; }
    const move = parseFloat($("f-move").value);
    if (move > 0) req.move_velocity_deg_per_s = move;
    if ($("f-rule").value) req.decision_rule = $("f-rule").value;
    if ($("f-serial").value.trim()) req.serial_number = $("f-serial").value.trim();
    if ($("f-operator").value.trim()) req.operator = $("f-operator").value.trim();
    return req;
  }

  // ---- an error of the API shown in place: its text under the form or the plan editor, the field it names
  // outlined (the validation's loc, else a field's name in the one-line detail) ----
  // a plan's test fields (the picker fills them, a saved plan keeps them)
  const PLAN_FIELDS = { method: "f-method", reducer: "f-reducer", max_torque_nm: "f-torque", cycles: "f-cycles",
    profile: "f-profile", rate_nm_per_s: "f-rate", step_nm: "f-step", dwell_s: "f-dwell", positions: "f-positions",
    rates: "f-rates", move_velocity_deg_per_s: "f-move", decision_rule: "f-rule", input_speed_rpm: "f-input-speed",
    load_torque_nm: "f-load", revolutions: "f-revolutions", ramps: "f-ramps", creep_deg_per_s: "f-creep",
    speeds_rpm: "f-speeds" };
  const FIELD_IDS = { ...PLAN_FIELDS, serial_number: "f-serial", operator: "f-operator", name: "p-name", note: "p-note" };
  // a field's input: dwell_s is the stepped profile's dwell, or a turning test's hold per speed
  function fieldId(key) { return key === "dwell_s" && $("f-method").value !== "stiffness" ? "f-hold" : FIELD_IDS[key]; }
  function clearInvalid() {
    for (const el of document.querySelectorAll(".invalid")) { el.classList.remove("invalid"); el.removeAttribute("aria-invalid"); }
  }
  function fieldOf(error) {
    const loc = ((error.errors || [])[0] || {}).loc || [];
    for (const part of [...loc].reverse()) if (FIELD_IDS[part]) return fieldId(part);
    const names = Object.keys(FIELD_IDS).filter((k) => k.includes("_")).sort((a, b) => b.length - a.length);
    for (const name of names) if (String(error.detail || "").includes(name)) return fieldId(name);
    return null;
  }
  function showError(error, where) {
    clearInvalid();
    const id = fieldOf(error);
    if (id) { $(id).classList.add("invalid"); $(id).setAttribute("aria-invalid", "true"); }
    if (where === "plan") { $("plan-error").textContent = error.message; message(""); }
    else { $("plan-error").textContent = ""; message(error.message, true); }
  }
  $("test-form").addEventListener("input", (ev) => { if (ev.target.classList) ev.target.classList.remove("invalid"); });

  $("test-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    clearInvalid();
    const req = formRequest();
    const planId = $("f-plan").value;
    try {
      // a saved plan starts through POST /api/tests/from-plan: the plan's request with this unit's fields
      const res = planId
        ? await api("POST", "/api/tests/from-plan", Object.assign({ plan_id: parseInt(planId, 10) },
          req.serial_number ? { serial_number: req.serial_number } : {}, req.operator ? { operator: req.operator } : {}))
        : await api("POST", "/api/tests", req);
      if (state.activeId !== res.id) {  // the event channel may already have reported this test
        resetLoop();
        startMethod(planId ? (((state.plans || new Map()).get(planId) || {}).request || {}).method : req.method);
        setTestState(res.id, res.status);
      }
      message(t("dash.started", { id: res.id }));
    } catch (e) { showError(e, "test"); }
  });

  $("abort").addEventListener("click", async () => {
    if (!state.activeId) return;
    try { await api("POST", "/api/tests/" + encodeURIComponent(state.activeId) + "/abort"); message(t("dash.abort_requested")); }
    catch (e) { message(e.message, true); }
  });

  // ---- saved plans: the picker fills the form (its test fields fixed) and starts the plan; the editor keeps the
  // form's test as the next version of a named plan ("Edit plan" opens a picked plan's fields for its next
  // version; an operator, without the right plan.edit, sees no editor) ----
  async function loadPlans(selectId) {
    let plans = [];
    try { plans = await api("GET", "/api/plans"); } catch (e) { return; }
    state.plans = new Map(plans.map((p) => [String(p.id), p]));
    const select = $("f-plan");
    select.length = 1;
    for (const p of plans) {
      const o = document.createElement("option");
      o.value = p.id; o.textContent = t("dash.plan_option", { name: p.name, version: p.version });
      o.title = p.note || "";
      select.appendChild(o);
    }
    if (selectId !== undefined) { select.value = String(selectId); showPlan(); }
  }
  function showPlan() {
    const plan = (state.plans || new Map()).get($("f-plan").value);
    const form = $("test-form");
    form.classList.toggle("from-plan", !!plan);
    const turning = plan && plan.request.method && plan.request.method !== "stiffness";
    for (const [key, pick] of Object.entries(PLAN_FIELDS)) {
      const id = key === "dwell_s" && turning ? "f-hold" : pick;
      const el = $(id);
      el.disabled = !!plan;
      el.closest("label").classList.toggle("plan-fixed", !!plan);
      if (key === "dwell_s") { $("f-hold").disabled = !!plan; $("f-hold").closest("label").classList.toggle("plan-fixed", !!plan); }
      if (!plan) continue;
      const v = key === "method" ? plan.request.method || "stiffness" : plan.request[key];
      el.value = v === undefined || v === null ? "" : Array.isArray(v) ? v.join(",") : String(v);
    }
    if (plan) { form.classList.toggle("stepped", plan.request.profile === "stepped"); pickMethod(); }
    $("edit-plan").hidden = !plan || !state.mayEditPlans;
  }
  $("f-plan").addEventListener("change", () => { clearInvalid(); $("plan-error").textContent = ""; showPlan(); });
  $("edit-plan").addEventListener("click", () => {
    const plan = (state.plans || new Map()).get($("f-plan").value);
    if (!plan) return;
    $("f-plan").value = "";  // the form is the plan's test again, free to change; saving makes its next version
    showPlan();
    $("p-name").value = plan.name;
    $("p-note").value = "";
    $("p-note").focus();
    message(t("dash.editing_plan", { name: plan.name, version: plan.version, next: plan.version + 1 }));
  });
  $("save-plan").addEventListener("click", async () => {
    clearInvalid();
    const name = $("p-name").value.trim();
    if (!name) {
      showError(Object.assign(new Error(t("dash.plan_name_missing")), { errors: [{ loc: ["body", "name"] }] }), "plan");
      $("p-name").focus();
      return;
    }
    const req = formRequest();
    delete req.serial_number; delete req.operator;
    try {
      const saved = await api("POST", "/api/plans", { name, note: $("p-note").value.trim(), request: req });
      $("plan-error").textContent = "";
      $("p-note").value = "";
      message(t("dash.plan_saved", { name: saved.name, version: saved.version }));
      await loadPlans(saved.id);
    } catch (e) { showError(e, "plan"); }
  });

  // ---- the bench's settings (GET/PUT /api/settings), for an admin: errors under the form, the field outlined ----
  const SETTINGS = ["bench_display_name", "default_language", "session_lifetime_h", "lockout_failures_per_user",
    "lockout_failures_per_address", "lockout_s"];
  async function loadSettings(mayEdit) {
    $("settings-box").hidden = !mayEdit;
    if (!mayEdit) return;
    try {
      const current = await api("GET", "/api/settings");
      for (const key of SETTINGS) $("s-" + key).value = current[key] === null ? "" : String(current[key]);
    } catch (e) { $("settings-error").textContent = e.message; }
  }
  $("settings-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    for (const el of $("settings-form").querySelectorAll(".invalid")) el.classList.remove("invalid");
    const change = {};
    for (const key of SETTINGS) {
      const el = $("s-" + key), raw = el.value.trim();
      change[key] = el.type === "number" ? (raw === "" ? null : Number(raw)) : (raw === "" ? null : raw);
    }
    try {
      const saved = await api("PUT", "/api/settings", change);
      $("settings-error").textContent = "";
      message(t("dash.settings_saved"));
      $("bench-name").textContent = saved.bench_display_name || $("bench-name").textContent;
    } catch (e) {
      $("settings-error").textContent = e.message;
      const loc = ((e.errors || [])[0] || {}).loc || [];
      const key = [...loc].reverse().find((part) => SETTINGS.includes(part)) ||
        SETTINGS.find((name) => String(e.detail || "").startsWith(name));
      if (key) $("s-" + key).classList.add("invalid");
    }
  });

  // ---- who is signed in (GET /api/me): the token's user, the session's, or a sign-in form ----
  async function whoAmI() {
    const who = $("who");
    try {
      const me = await api("GET", "/api/me");
      who.innerHTML = escapeHtml(t("dash.signed_in_as", { name: me.name, role: t("role." + me.role) })) +
        (me.via === "session" ? ` <button type="button" id="sign-out">${escapeHtml(t("dash.sign_out"))}</button>` : "");
      $("login-box").hidden = true;
      const out = $("sign-out");
      if (out) out.addEventListener("click", async () => { try { await api("POST", "/api/logout"); } catch (e) { /* gone */ } whoAmI(); });
      state.mayEditPlans = me.rights.includes("plan.edit");
      $("save-plan").disabled = !state.mayEditPlans;
      $("plan-editor").hidden = !state.mayEditPlans;
      showPlan();
      $("start").title = me.rights.includes("test.start") ? "" : t("dash.plan");
      loadSettings(me.rights.includes("settings.edit"));
    } catch (e) {
      who.textContent = "";
      $("login-box").hidden = false;
      state.mayEditPlans = false;  // a token typed into the form may still save a plan: the API decides
      $("plan-editor").hidden = false;
      $("save-plan").disabled = false;
      showPlan();
      loadSettings(false);
    }
  }
  $("login-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    try {
      await api("POST", "/api/login", { name: $("l-name").value.trim(), password: $("l-password").value });
      $("l-password").value = "";
      message("");
      await whoAmI();
    } catch (e) { message(e.message, true); }
  });

  window.tcms = { state, loopPoints: () => state.loop.x.length };
  setTestState(null, "idle");
  connectEvents();
  loadHistory();
  loadModel();
  loadPlans();
  whoAmI();
  loadDiscrepancyHistory();
})();
