// TCMS-DAQ pages in the user's language: the catalogues come from /i18n/messages.js (tcms_daq/service/messages.py,
// one per language). The language is ?lang=, else the one chosen with the switch (kept in this browser), else the
// bench's default language (its admin's setting), else the first of the browser's languages the catalogue has,
// else English. Elements name their words by key:
// data-i18n (text), data-i18n-placeholder, data-i18n-title.
"use strict";
const TcmsI18n = (() => {
  const all = window.TCMS_MESSAGES || { en: {} };
  const params = new URLSearchParams(location.search);

  function primary(tag) { return String(tag || "").toLowerCase().split("-")[0]; }
  function pick() {
    let kept = null;
    try { kept = localStorage.getItem("tcmsLang"); } catch (e) { kept = null; }
    const candidates = [params.get("lang"), kept, window.TCMS_DEFAULT_LANG,
      ...(navigator.languages || [navigator.language])];
    for (const c of candidates) if (c && all[primary(c)]) return primary(c);
    return "en";
  }
  const lang = pick();
  const words = Object.assign({}, all.en || {}, all[lang] || {});

  /** The text of `key` with its {fields} filled; the key itself when no catalogue has it. */
  function t(key, fields) {
    const template = Object.prototype.hasOwnProperty.call(words, key) ? words[key] : key;
    return fields ? template.replace(/\{(\w+)\}/g, (m, name) => (name in fields ? String(fields[name]) : m)) : template;
  }

  function apply(root) {
    document.documentElement.lang = lang === "zh" ? "zh-CN" : "en";
    for (const el of (root || document).querySelectorAll("[data-i18n]")) el.textContent = t(el.dataset.i18n);
    for (const el of (root || document).querySelectorAll("[data-i18n-placeholder]")) el.placeholder = t(el.dataset.i18nPlaceholder);
    for (const el of (root || document).querySelectorAll("[data-i18n-title]")) el.title = t(el.dataset.i18nTitle);
  }

  /** A <select> of languages: shows the one in use; a choice is kept for this browser and the page reloads. */
  function bindSwitch(select) {
    select.value = lang;
    select.addEventListener("change", () => {
      try { localStorage.setItem("tcmsLang", select.value); } catch (e) { /* private mode: this page only */ }
      const next = new URLSearchParams(location.search);
      next.set("lang", select.value);
      location.search = next.toString();
    });
  }

  /** A warning or reason of the core ({code, params, text}; tcms_daq/analysis/notices.py) in this page's language:
   * the catalogue's notice.<code> with its params, else the core's English text; a stage's notice says which. */
  function notice(n) {
    const key = "notice." + n.code;
    // a notice inside a notice (a left-out loop's gaps) in this language too
    const param = (v) => (Array.isArray(v) ? v.map(param).join(t("list_separator"))
      : v && typeof v === "object" ? notice(v) : v);
    const params = Object.fromEntries(Object.entries(n.params || {}).map(([k, v]) => [k, param(v)]));
    let body = n.code && lang !== "en" && Object.prototype.hasOwnProperty.call(all[lang] || {}, key)
      ? t(key, params) : String(n.text || "");
    if (n.stage && (n.stage.kind === "position" || n.stage.kind === "rate")) {
      body = t("notice.stage_" + n.stage.kind, { number: n.stage.number, text: body });
    }
    return body;
  }
  /** The warnings of a results document in this page's language (its notices when they match one to one). */
  function warnings(res) {
    const texts = res.warnings || [], kept = res.notices;
    return Array.isArray(kept) && kept.length === texts.length ? kept.map(notice) : texts.map(String);
  }
  /** Why a verdict is undecided whatever the values, in this page's language. */
  function reasons(verdict) {
    const texts = verdict.reasons || [], kept = verdict.reason_notices;
    return Array.isArray(kept) && kept.length === texts.length ? kept.map(notice) : texts.map(String);
  }
  /** An uncertainty source's name (the core's English) in this page's language; the name when none is known. */
  function source(name) {
    if (lang === "en" || typeof name !== "string") return String(name);
    const own = all[lang] || {};
    if (Object.prototype.hasOwnProperty.call(own, "source." + name)) return own["source." + name];
    for (const [pattern, key] of window.TCMS_SOURCE_PATTERNS || []) {
      const found = new RegExp(pattern).exec(name);
      if (found && Object.prototype.hasOwnProperty.call(own, key)) return t(key, found.groups || {});
    }
    return name;
  }
  /** A decision rule's name (guarded, simple). */
  function rule(name) { return name === "guarded" || name === "simple" ? t("rule." + name) : String(name); }

  /** `path` with this page's language (?lang=), for reports and certificates. */
  function withLang(path) { return path + (path.includes("?") ? "&" : "?") + "lang=" + lang; }

  return { lang, t, apply, bindSwitch, withLang, notice, warnings, reasons, rule, source };
})();
