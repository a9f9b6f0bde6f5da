// TCMS-DAQ discrepancy on any stored run, shared by the dashboard and the fleet page: start an analysis
// (POST /api/discrepancy), say what it found in words (with the experiment or run that would separate look-alikes),
// offer the run that separates them (a button that starts it) and show the analyses' history
// (GET /api/discrepancy). Kept apart from the pages' own code.
"use strict";
const TcmsDiscrepancy = (() => {
  const { withToken, escapeHtml } = TcmsSession;
  const fmt = (v) => (typeof v === "number"
    ? (Math.abs(v) >= 1e5 || (v !== 0 && Math.abs(v) < 1e-3) ? v.toExponential(4) : +v.toPrecision(6)) : String(v));
  // a named parameter as "value ± U (k = …)" with its expanded uncertainty (Student's k for the jackknife's groups)
  const parameter = (e, k, v) => {
    const U = e.expanded_uncertainty && e.expanded_uncertainty[k];
    return typeof U === "number" && U > 0 ? TcmsRounding.withU(v, U, e.coverage_factor) : fmt(v);
  };
  const rms = (v) => (typeof v === "number" ? v.toFixed(3) + "″" : "–");

  async function api(method, path, body) { return (await TcmsSession.request(method, path, body)).data; }

  // What an analysis found, in this page's language: the verdict and its sentences (verdict_notices, the core's
  // English where the catalogue lacks a code), the names, the look-alikes and the held-out RMS before → after.
  function describe(d) {
    const { t, notice } = TcmsI18n;
    const named = d.effects.length
      ? t("disc.named", { names: d.effects.map((e) => e.name + " (" + Object.entries(e.parameters)
        .map(([k, v]) => k + " = " + parameter(e, k, v)).join(", ") + ")").join("; ") })
      : t("disc.named_nothing");
    const then = t("list_separator");
    const aliases = d.aliases.map((a) => then + t("disc.aliases", { names: a.names.join(" / ") }) +
      (a.separating_experiment ? " — " + t("disc.to_separate", { how: a.separating_experiment }) : "")).join("");
    const sentences = Array.isArray(d.verdict_notices) && d.verdict_notices.length
      ? d.verdict_notices.map(notice).join(" ") : (d.verdict_words || "");
    const verdict = d.verdict ? t("disc.verdict_said", { verdict: t("disc.verdict." + d.verdict), text: sentences }) + " " : "";
    const provisional = d.names_provisional && d.effects.length ? " " + t("disc.provisional") : "";
    return verdict + named + provisional + aliases + then +
      t("disc.held_out", { before: rms(d.cv_rms_before_arcsec), after: rms(d.cv_rms_after_arcsec) });
  }

  // The "missing effects" button of a stored run (the dashboard's recent tests, the fleet list): a click calls
  // onClick(id, button).
  function findEffectsButton(id, onClick) {
    const button = document.createElement("button");
    button.type = "button";
    button.className = "find-effects";
    button.dataset.run = id;
    button.textContent = TcmsI18n.t("dash.missing_effects");
    button.title = TcmsI18n.t("dash.missing_effects_hint");
    button.addEventListener("click", () => onClick(id, button));
    return button;
  }

  // Start an analysis of a stored run; resolves to the analysis (the API's document).
  function start(runId) { return api("POST", "/api/discrepancy", { run_id: runId }); }

  // Fill a table body with the latest analyses (optionally of one run): when, run, model version, verdict, names.
  async function history(tbody, runId, limit = 8) {
    let items = [];
    try { items = await api("GET", "/api/discrepancy?limit=" + (runId ? 1000 : limit)); } catch (e) { return []; }
    if (runId) items = items.filter((a) => a.run_id === runId).slice(0, limit);
    tbody.innerHTML = "";
    tbody.closest("table").hidden = !items.length;  // no empty table taking room beside the results
    for (const a of items) {
      const tr = document.createElement("tr");
      tr.dataset.analysis = a.id;
      const names = (a.effects || []).map((e) => (typeof e === "string" ? e : e.name)).join(", ") || "—";
      tr.innerHTML = `<td>${escapeHtml((a.created_at || "").replace("T", " ").slice(0, 19))}</td>` +
        `<td>${escapeHtml(a.run_id)}</td><td>v${escapeHtml(String(a.model_version))}</td>` +
        `<td>${escapeHtml(a.verdict ? TcmsI18n.t("disc.verdict." + a.verdict) : "")}</td><td>${escapeHtml(names)} ` +
        `<a href="${escapeHtml(withToken("/api/discrepancy/" + encodeURIComponent(a.id) + "/report"))}" ` +
        `target="_blank">${escapeHtml(TcmsI18n.t("disc.report"))}</a></td>`;
      tbody.appendChild(tr);
    }
    return items;
  }

  // Where the run cannot separate look-alikes, a button per suggested run (the analysis's suggested_runs: a POST
  // /api/tests body) placed after `after`; a click starts exactly that run. Called with null it removes them.
  function offerRuns(after, d) {
    const t = TcmsI18n.t;
    const old = after.parentNode.querySelector(".suggested-runs");
    if (old) old.remove();
    const runs = (d && d.suggested_runs) || [];
    if (!runs.length) return;
    const box = document.createElement("p");
    box.className = "suggested-runs";
    for (const s of runs) {
      const button = document.createElement("button");
      button.type = "button";
      button.className = "start-suggested secondary";
      button.dataset.kind = s.kind;
      const names = s.names.join(" / ");
      button.textContent = s.kind === "tip_holds"
        ? t("disc.run_tip_holds", { names, step: fmt(s.request.step_nm), dwell: fmt(s.request.dwell_s) })
        : t("disc.run_second_rate", { names, rates: (s.request.rates || []).map(fmt).join(" / ") });
      button.title = s.why;
      button.addEventListener("click", async () => {
        button.disabled = true;
        try {
          const run = await api("POST", "/api/tests", s.request);
          const said = document.createElement("span");
          said.className = "suggested-started";
          said.dataset.run = run.id;
          said.textContent = " " + t("disc.run_started", { id: run.id, names });
          button.after(said);
        } catch (e) {
          button.disabled = false;
          const said = document.createElement("span");
          said.className = "error";
          said.textContent = " " + e.message;
          button.after(said);
        }
      });
      box.appendChild(button);
    }
    after.after(box);
  }

  return { describe, start, history, offerRuns, findEffectsButton };
})();
