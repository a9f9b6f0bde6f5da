// TCMS-DAQ dashboard: a turning test's view (docs/transmission.md, the results contract). The transmission error
// against the output angle per direction and its order spectrum — live from the te_live events while it runs (the
// spectrum of what has arrived, over the angle turned so far), the evaluated curve, spectrum and lines (order,
// component, amplitude ± U, phase) once stored —; each starting-torque ramp around its breakaway; the no-load torque
// per speed; the efficiency per direction. What is drawn comes from GET /api/tests/{id}/curves
// (tcms_daq/service/method_views.py), the words from the catalogue (certificate.* for those the certificate shares).
"use strict";
const TcmsMethodView = (() => {
  const { t } = TcmsI18n;
  const $ = (id) => document.getElementById(id);
  const COLOUR = { forward: "#1f5fa8", reverse: "#d9771e" };
  const FIT = { forward: "#0b2f5a", reverse: "#7a3c05" };
  const RAMP_SHADES = { forward: ["#1f5fa8", "#4f86c6", "#86aedb"], reverse: ["#d9771e", "#e89a52", "#f2bd8a"] };
  const LINE_COLOUR = "#b3261e";
  const LIVE_MAX_POINTS = 3000;       // per direction (decimated by stride doubling beyond)
  const SPECTRUM_GRID = 2048;         // points of the live spectrum's even angle grid
  const SPECTRUM_MAX_ORDER = 260;     // the live spectrum's band, orders per output revolution
  const LIVE_MIN_SPAN_DEG = 20;       // no live spectrum over less output angle than this
  const HEIGHT = 250;

  const view = { method: null, plots: [], live: null };

  function width(el) { return Math.max(300, el.clientWidth - 4); }
  const facets = [{ scale: "x", auto: true }, { scale: "y", auto: true }];
  function line(label, stroke, extra) {
    return Object.assign({ label, stroke, width: 1.3, paths: uPlot.paths.linear(), points: { show: false }, facets }, extra || {});
  }
  function fmt(v, digits) { return typeof v === "number" && isFinite(v) ? String(+v.toPrecision(digits || 4)) : "–"; }

  // a component's name in this page's language: "pin_ring 2×" → 针齿圈 2×; several joined by " / "
  function component(name) {
    if (!name) return t("dash.te_no_component");
    return String(name).split(" / ").map((part) => {
      const twice = part.endsWith(" 2×");
      const base = twice ? part.slice(0, -3) : part;
      const key = "certificate.component_" + base;
      const word = t(key) === key ? base.replace(/_/g, " ") : t(key);
      return twice ? word + " 2×" : word;
    }).join(" / ");
  }

  // markers with their U, a band and labelled markers drawn over a plot (uPlot's mode 2 draws the paths; these are
  // ours): marks = {bars: [{x, y, U, colour}], band: [{x0, x1, lo, hi, fill}], labels: [{x, y, text}]}
  function overlay(marks) {
    return (u) => {
      const ctx = u.ctx, r = devicePixelRatio;
      ctx.save();
      ctx.beginPath();
      ctx.rect(u.bbox.left, u.bbox.top, u.bbox.width, u.bbox.height);
      ctx.clip();
      const px = (v, s) => u.valToPos(v, s, true);
      for (const b of marks.band || []) {
        ctx.fillStyle = b.fill;
        const y0 = px(b.lo, "y"), y1 = px(b.hi, "y");
        ctx.fillRect(px(b.x0, "x"), Math.min(y0, y1), px(b.x1, "x") - px(b.x0, "x"), Math.abs(y1 - y0));
      }
      for (const b of marks.bars || []) {
        const x = px(b.x, "x"), y = px(b.y, "y");
        ctx.strokeStyle = b.colour; ctx.fillStyle = b.colour; ctx.lineWidth = 1.5 * r;
        if (b.U > 0) {
          const y0 = px(b.y - b.U, "y"), y1 = px(b.y + b.U, "y"), w = 4 * r;
          ctx.beginPath();
          ctx.moveTo(x, y0); ctx.lineTo(x, y1); ctx.moveTo(x - w, y0); ctx.lineTo(x + w, y0);
          ctx.moveTo(x - w, y1); ctx.lineTo(x + w, y1);
          ctx.stroke();
        }
        ctx.beginPath(); ctx.arc(x, y, 3.5 * r, 0, 2 * Math.PI); ctx.fill();
      }
      for (const st of marks.stems || []) {  // a spectrum: a stem from zero at each bin
        ctx.strokeStyle = st.colour; ctx.lineWidth = 1.2 * r;
        ctx.beginPath();
        const y0 = px(0, "y");
        for (let i = 0; i < st.x.length; i++) {
          const x = px(st.x[i], "x");
          ctx.moveTo(x, y0); ctx.lineTo(x, px(st.y[i], "y"));
        }
        ctx.stroke();
      }
      // labelled markers, the largest first; a label that would cover one already placed moves up a line, and one
      // that would leave the plot on the right is written to the left of its marker
      ctx.font = `${11 * r}px system-ui, sans-serif`;
      ctx.textAlign = "left";  // uPlot leaves its axes' alignment set
      ctx.textBaseline = "alphabetic";
      const placed = [], h = 13 * r;
      for (const l of [...(marks.labels || [])].sort((a, b) => b.y - a.y)) {
        const x = px(l.x, "x"), y = px(l.y, "y");
        ctx.fillStyle = LINE_COLOUR;
        ctx.beginPath(); ctx.arc(x, y, 3.5 * r, 0, 2 * Math.PI); ctx.fill();
        const w = ctx.measureText(l.text).width;
        let left = x + 5 * r;
        if (left + w > u.bbox.left + u.bbox.width) left = x - 5 * r - w;
        left = Math.max(u.bbox.left + 2 * r, left);
        let top = y - 5 * r - h;
        const hits = (t) => placed.some((p) => left < p.right && left + w > p.left && t < p.bottom && t + h > p.top);
        while (hits(top) && top > u.bbox.top - h) top -= h;
        if (top < u.bbox.top) { top = y + 5 * r; while (hits(top)) top += h; }
        placed.push({ left, right: left + w, top, bottom: top + h });
        ctx.fillStyle = "#1d2430";
        ctx.fillText(l.text, left, top + h - 3 * r);
      }
      ctx.restore();
    };
  }

  /** A y axis's size (px) that holds its widest tick label (a turned output's angle in arcsec has seven digits and
   * more: a fixed size drew them over the axis label). uPlot calls it with the axis's formatted tick values. */
  function axisSize(self, values, axisIdx, cycleNum) {
    const axis = self.axes[axisIdx];
    if (cycleNum > 1) return axis._size;
    let size = axis.ticks.size + axis.gap;
    const longest = (values || []).reduce((acc, v) => (String(v).length > acc.length ? String(v) : acc), "");
    if (longest !== "") {
      self.ctx.font = axis.font[0];
      size += self.ctx.measureText(longest).width / devicePixelRatio;
    }
    return Math.max(50, Math.ceil(size) + 4);
  }

  function plot(el, axes, series, data, options) {
    const o = options || {};
    el.innerHTML = "";
    el.hidden = false;
    const marks = o.marks || {};
    const u = new uPlot({
      mode: 2, width: width(el), height: HEIGHT,
      scales: Object.assign({ x: Object.assign({ time: false, auto: true }, o.xRange ? { range: o.xRange } : {}),
                              y: Object.assign({ auto: true }, o.yRange ? { range: o.yRange } : {}) }, o.scales || {}),
      axes: [{ label: axes[0] }, { label: axes[1], size: axisSize }],
      series: [{}, ...series],
      legend: { show: true, live: false },
      cursor: { show: false },
      hooks: { draw: [overlay(marks)] },
    }, [null, ...data], el);
    u.marks = marks;
    view.plots.push(u);
    return u;
  }

  function clear() {
    for (const u of view.plots) u.destroy();
    view.plots = [];
    for (const id of ["plot-method-a", "plot-method-b"]) { $(id).innerHTML = ""; $(id).hidden = true; }
    $("mv-title-b").textContent = "";
    $("te-lines").hidden = true;
    $("mv-state").textContent = "";
  }

  /** Show the loop (stiffness) or a turning method's view. */
  function show(method) {
    const turning = !!method && method !== "stiffness";
    $("loop-view").hidden = turning;
    $("method-view").hidden = !turning;
    if (turning && method !== view.method) clear();
    view.method = turning ? method : null;
    if (turning) $("mv-title").textContent = t("certificate.figure_" + method);
  }

  // ---- transmission error ----
  function teAxes() { return [t("certificate.axis_output_angle"), t("dash.axis_te")]; }
  function spectrumAxes() { return [t("certificate.axis_order"), t("certificate.axis_te_amplitude")]; }
  const LOG_X = { x: { time: false, distr: 3, log: 10, auto: true } };
  const FROM_ZERO = (u, lo, hi) => [0, (hi > 0 ? hi : 1) * 1.15];
  const NO_PATH = () => null;  // a series drawn by the overlay (stems), kept for its legend and its scale

  // the spectrum of the TE that has arrived: resampled onto an even grid of the output angle turned so far, its
  // trend removed, the amplitude at each order k / (revolutions turned) up to SPECTRUM_MAX_ORDER
  function liveSpectrum(xs, ys) {
    if (xs.length < 16) return null;
    const idx = xs.map((_, i) => i).sort((a, b) => xs[a] - xs[b]);
    const x = idx.map((i) => xs[i]), y = idx.map((i) => ys[i]);
    const span = x[x.length - 1] - x[0];
    if (!(span >= LIVE_MIN_SPAN_DEG)) return null;
    const n = SPECTRUM_GRID, g = new Float64Array(n);
    let j = 0;
    for (let k = 0; k < n; k++) {
      const at = x[0] + (span * k) / (n - 1);
      while (j < x.length - 2 && x[j + 1] < at) j++;
      const w = x[j + 1] > x[j] ? (at - x[j]) / (x[j + 1] - x[j]) : 0;
      g[k] = y[j] + Math.min(1, Math.max(0, w)) * (y[j + 1] - y[j]);
    }
    let sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (let k = 0; k < n; k++) { sx += k; sy += g[k]; sxx += k * k; sxy += k * g[k]; }
    const b = (n * sxy - sx * sy) / (n * sxx - sx * sx), a = (sy - b * sx) / n;
    for (let k = 0; k < n; k++) g[k] -= a + b * k;
    const revs = span / 360, bins = Math.min(Math.floor(n / 2) - 1, Math.floor(SPECTRUM_MAX_ORDER * revs));
    const orders = [], amps = [];
    for (let k = 1; k <= bins; k++) {
      let re = 0, im = 0;
      const w = (2 * Math.PI * k) / n;
      for (let m = 0; m < n; m++) { re += g[m] * Math.cos(w * m); im -= g[m] * Math.sin(w * m); }
      orders.push(k / revs);
      amps.push((2 / n) * Math.hypot(re, im));
    }
    return { orders, amps, revs };
  }

  function startLive() {
    show("transmission-error");
    clear();
    view.live = { forward: { x: [], y: [], stride: 1, n: 0 }, reverse: { x: [], y: [], stride: 1, n: 0 }, last: null,
                  dirty: false, spectrumAt: 0 };
    $("mv-state").textContent = "(" + t("dash.live_preliminary") + ")";
    plot($("plot-method-a"), teAxes(), ["forward", "reverse"].map((d) => line(t("certificate.direction_" + d), COLOUR[d])),
         [[[], []], [[], []]]);
    $("mv-title-b").textContent = t("dash.te_spectrum_live");
    plot($("plot-method-b"), spectrumAxes(), [line(t("dash.te_spectrum_measured"), "#5b6678", { paths: NO_PATH })],
         [[[], []]], { scales: LOG_X, yRange: FROM_ZERO, marks: { stems: [{ x: [], y: [], colour: "#5b6678" }] } });
  }

  /** A te_live event of the running transmission-error test. Each direction's angle and TE count from where it
   * began; the reverse, which begins where the forward ended, is drawn from there: both directions over the same
   * output angle, the lost motion under the light load the offset between them. */
  function onTeLive(e) {
    if (!view.live) startLive();
    const d = view.live[e.direction];
    if (!d) return;
    if (!d.x.length && d.n === 0) {
      const other = view.live[e.direction === "reverse" ? "forward" : "reverse"];
      d.from = other.x.length ? [other.x[other.x.length - 1], other.y[other.y.length - 1]] : [0, 0];
    }
    for (let i = 0; i < e.output_angle_deg.length; i++) {
      if (d.n++ % d.stride !== 0) continue;
      d.x.push(d.from[0] + e.output_angle_deg[i]); d.y.push(d.from[1] + e.te_arcsec[i]);
    }
    if (d.x.length > LIVE_MAX_POINTS) {
      d.x = d.x.filter((_, i) => i % 2 === 0); d.y = d.y.filter((_, i) => i % 2 === 0); d.stride *= 2;
    }
    view.live.last = e.direction;
    view.live.dirty = true;
  }

  function paintLive() {
    const L = view.live;
    if (L && L.dirty && view.plots.length === 2) {
      L.dirty = false;
      view.plots[0].setData([null, [L.forward.x, L.forward.y], [L.reverse.x, L.reverse.y]]);
      const now = performance.now();
      if (now - L.spectrumAt > 400) {  // at most a few spectra a second
        L.spectrumAt = now;
        const s = liveSpectrum(L[L.last].x, L[L.last].y);
        if (s) {
          view.plots[1].marks.stems[0] = { x: s.orders, y: s.amps, colour: "#5b6678" };
          view.plots[1].setData([null, [s.orders, s.amps]]);
          $("mv-title-b").textContent = t("dash.te_spectrum_live_over", {
            direction: t("certificate.direction_" + L.last), revolutions: fmt(s.revs, 2) });
        } else L.dirty = true;  // again at the next frame, with more angle turned
      }
    }
    requestAnimationFrame(paintLive);
  }
  requestAnimationFrame(paintLive);

  function showTe(c) {
    const curve = c.te_curve || {}, spectrum = c.te_spectrum || {};
    const dirs = ["forward", "reverse"].filter((d) => curve[d]);
    const name = (d) => t("certificate.direction_" + d);
    plot($("plot-method-a"), teAxes(), [
      ...dirs.map((d) => line(t("certificate.legend_te_measured", { direction: name(d) }), COLOUR[d], { width: 1 })),
      ...dirs.map((d) => line(t("certificate.legend_te_lines", { direction: name(d) }), FIT[d], { dash: [5, 4], width: 1.2 })),
    ], [...dirs.map((d) => [curve[d].output_angle_deg, curve[d].te_arcsec]),
        ...dirs.map((d) => [curve[d].output_angle_deg, curve[d].te_fit_arcsec])]);
    const lines = c.te_lines || [];
    $("mv-title-b").textContent = t("certificate.figure_te_spectrum");
    const sdirs = ["forward", "reverse"].filter((d) => spectrum[d]);
    plot($("plot-method-b"), spectrumAxes(), sdirs.map((d) => line(name(d), COLOUR[d], { paths: NO_PATH })),
         sdirs.map((d) => [spectrum[d].order, spectrum[d].amplitude_arcsec]), { scales: LOG_X, yRange: FROM_ZERO, marks: {
           stems: sdirs.map((d) => ({ x: spectrum[d].order, y: spectrum[d].amplitude_arcsec, colour: COLOUR[d] })),
           labels: lines.filter((l) => l.amplitude_arcsec > 0).map((l) => ({
             x: l.order, y: l.amplitude_arcsec, text: fmt(l.order, 4) + " " + component(l.component) })) } });
    showLines(lines);
  }

  function showLines(lines) {
    const esc = TcmsSession.escapeHtml;
    const table = $("te-lines");
    table.tHead.innerHTML = "<tr>" + ["certificate.col_order", "certificate.col_component", "certificate.col_amplitude",
      "certificate.col_phase"].map((k) => "<th>" + esc(t(k)) + "</th>").join("") + "</tr>";
    table.tBodies[0].innerHTML = lines.map((l) => {
      const u = l.uncertainty || {};
      const amplitude = TcmsRounding.withU(l.amplitude_arcsec, u.U, u.k);
      const phase = typeof l.phase_deg !== "number" ? "–"
        : l.u_phase_deg > 0 ? TcmsRounding.roundToU(l.phase_deg, l.u_phase_deg)[0] : fmt(l.phase_deg);
      return "<tr>" + [fmt(l.order, 5), component(l.component), amplitude, phase]
        .map((v, i) => (i ? "<td>" : "<th>") + esc(String(v)) + (i ? "</td>" : "</th>")).join("") + "</tr>";
    }).join("");
    table.hidden = !lines.length;
  }

  // ---- starting torque: each ramp's input torque and input angle against the time from its breakaway ----
  function showStarting(c) {
    const ramps = c.ramps || [];
    const seen = { forward: 0, reverse: 0 };
    const named = ramps.map((r) => {
      seen[r.direction] = (seen[r.direction] || 0) + 1;
      const shades = RAMP_SHADES[r.direction] || ["#5b6678"];
      return { colour: shades[(seen[r.direction] - 1) % shades.length],
               name: t("certificate.legend_ramp", { direction: t("certificate.direction_" + r.direction), n: seen[r.direction] }) };
    });
    const series = () => named.map((m) => line(m.name, m.colour));
    plot($("plot-method-a"), [t("certificate.axis_time_from_onset"), t("certificate.axis_input_torque")], series(),
         ramps.map((r) => [r.time_from_onset_s, r.input_torque_nm]), { marks: {
           bars: ramps.map((r) => ({ x: 0, y: r.direction === "reverse" ? -r.torque_nm : r.torque_nm, U: 0, colour: LINE_COLOUR })) } });
    $("mv-title-b").textContent = t("certificate.figure_starting_angle");
    plot($("plot-method-b"), [t("certificate.axis_time_from_onset"), t("dash.axis_input_angle")], series(),
         ramps.map((r) => [r.time_from_onset_s, r.input_angle_arcsec]));
  }

  // ---- no-load torque per speed ----
  function showNoLoad(c) {
    const speeds = c.speeds || [];
    const pts = (key) => [speeds.map((s) => s.speed_rpm), speeds.map((s) => (s[key] || {}).value)];
    const bars = [];
    for (const s of speeds) {
      for (const [key, colour] of [["no_load", LINE_COLOUR], ["forward", COLOUR.forward], ["reverse", COLOUR.reverse]]) {
        const q = s[key] || {};
        if (typeof q.value === "number") bars.push({ x: s.speed_rpm, y: q.value, U: q.U || 0, colour });
      }
    }
    const top = Math.max(...speeds.map((s) => s.speed_rpm), 1);
    const values = bars.map((b) => b.y + b.U);
    plot($("plot-method-a"), [t("certificate.axis_input_speed"), t("certificate.axis_no_load_torque")], [
      line(t("certificate.legend_no_load"), LINE_COLOUR, { width: 1.5 }),
      line(t("certificate.legend_no_load_direction", { direction: t("certificate.direction_forward") }), COLOUR.forward, { dash: [4, 4] }),
      line(t("certificate.legend_no_load_direction", { direction: t("certificate.direction_reverse") }), COLOUR.reverse, { dash: [4, 4] }),
    ], [pts("no_load"), pts("forward"), pts("reverse")], {
      marks: { bars }, xRange: () => [0, 1.08 * top], yRange: () => [0, 1.15 * Math.max(...values, 1e-3)] });
  }

  // ---- efficiency per direction: its blocks of whole input revolutions, the mean ± U as a band ----
  function showEfficiency(c) {
    const dirs = c.directions || [];
    const pct = (v) => (typeof v === "number" ? 100 * v : null);
    const band = dirs.filter((d) => typeof d.value === "number").map((d) => ({
      x0: 1, x1: Math.max(2, d.block_efficiencies.length), lo: pct(d.value - (d.U || 0)), hi: pct(d.value + (d.U || 0)),
      fill: d.direction === "forward" ? "rgba(31,95,168,0.14)" : "rgba(217,119,30,0.16)" }));
    const lo = Math.min(...band.map((b) => b.lo), 100), hi = Math.max(...band.map((b) => b.hi), 0);
    const pad = Math.max(0.5, 0.3 * (hi - lo));
    plot($("plot-method-a"), [t("certificate.axis_block"), t("certificate.axis_efficiency")],
         dirs.map((d) => line(t("certificate.legend_efficiency", { direction: t("certificate.direction_" + d.direction),
                                                                   value: TcmsRounding.withU(pct(d.value), pct(d.U), d.k, "%") }),
                              COLOUR[d.direction], { width: 1.5 })),
         dirs.map((d) => [d.block_efficiencies.map((_, i) => i + 1), d.block_efficiencies.map(pct)]),
         { marks: { band }, yRange: () => [lo - pad, hi + pad] });
  }

  /** A stored run's view from GET /api/tests/{id}/curves. */
  function showStored(c) {
    view.live = null;
    show(c.method);
    clear();
    if (c.method === "transmission-error") showTe(c);
    else if (c.method === "starting-torque") showStarting(c);
    else if (c.method === "no-load-torque") showNoLoad(c);
    else if (c.method === "efficiency") showEfficiency(c);
  }

  window.addEventListener("resize", () => {
    for (const u of view.plots) u.setSize({ width: width(u.root.parentElement), height: HEIGHT });
  });

  return { show, startLive, onTeLive, showStored, component, liveSpectrum, axisSize, state: view };
})();
