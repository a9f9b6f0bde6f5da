// TCMS-DAQ pages: a result as "value ± U (k = …)": U to two significant digits, the value to the same decimal place
// (as tcms_daq/analysis/rounding.py does for the table, the report and the certificate); "U not stated" without U.
"use strict";
const TcmsRounding = (() => {
  /** [value, U] as strings: U to two significant digits, the value to the same decimal place. */
  function roundToU(value, U) {
    let exp = Math.floor(Math.log10(U)) - 1;
    let r = Math.round(U / Math.pow(10, exp)) * Math.pow(10, exp);
    if (r >= Math.pow(10, exp + 2)) { exp += 1; r = Math.round(U / Math.pow(10, exp)) * Math.pow(10, exp); }
    const decimals = Math.max(0, -exp);
    const v = Math.round(value / Math.pow(10, exp)) * Math.pow(10, exp);
    return [v.toFixed(decimals), r.toFixed(decimals)];
  }
  // three significant digits for a value without a stated U (never six)
  function fmt3(v) { return typeof v === "number" ? String(+v.toPrecision(3)) : "–"; }
  /** "v ± U (k = …)" (the unit, if any, after U); without a U three significant digits and "U not stated". */
  function withU(value, U, k, unit) {
    const suffix = unit ? (unit === "″" ? unit : " " + unit) : "";
    if (typeof value !== "number" || !isFinite(value)) return "–";
    if (typeof U !== "number" || !(U > 0)) return fmt3(value) + suffix + " (" + TcmsI18n.t("res.u_not_stated") + ")";
    const [v, u] = roundToU(value, U);
    return `${v} ± ${u}${suffix}` + (typeof k === "number" ? ` (k = ${k.toFixed(2)})` : "");
  }
  return { roundToU, withU, fmt3 };
})();
