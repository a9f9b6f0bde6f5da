// TCMS-DAQ pages: what the dashboard and the fleet page share. The API token (?token=… printed by `tcms serve`)
// is kept for this tab and taken out of the address bar; requests carry it as a bearer header, links and
// WebSockets (which cannot set headers) as ?token= (the service masks it in its access log). Without a token, a
// signed-in user's session cookie is the credential (POST /api/login).
"use strict";
const TcmsSession = (() => {
  const params = new URLSearchParams(location.search);
  if (params.get("token")) {
    sessionStorage.setItem("tcmsToken", params.get("token"));
    params.delete("token");
    history.replaceState(null, "", location.pathname + (params.toString() ? "?" + params : ""));
  }

  let field = null;
  function token() { return field ? field.value.trim() : (sessionStorage.getItem("tcmsToken") || ""); }

  /** Show the kept token in `input`; a changed token is kept for the tab, then `onChange` runs. */
  function bindTokenField(input, onChange) {
    field = input;
    input.value = sessionStorage.getItem("tcmsToken") || "";
    input.addEventListener("change", () => {
      sessionStorage.setItem("tcmsToken", token());
      if (onChange) onChange();
    });
  }

  function withToken(path) {
    const t = token();
    return t ? path + (path.includes("?") ? "&" : "?") + "token=" + encodeURIComponent(t) : path;
  }

  /** A JSON request; resolves to {data, response}, throws Error("status: detail") when not ok (the error keeps
   * .status, .detail and the validation's .errors, so a page can show it by the field it names). */
  async function request(method, path, body) {
    const headers = { "X-Requested-By": "tcms" };  // a signed-in change must carry it (no cross-site forgery)
    const t = token();
    if (t) headers["Authorization"] = "Bearer " + t;
    if (body !== undefined) headers["Content-Type"] = "application/json";
    const response = await fetch(path, { method, headers, credentials: "same-origin",
                                         body: body === undefined ? undefined : JSON.stringify(body) });
    let data = null;
    try { data = await response.json(); } catch (e) { data = null; }
    if (!response.ok) {
      const detail = data && data.detail ? (typeof data.detail === "string" ? data.detail : JSON.stringify(data.detail)) : response.statusText;
      const error = new Error(`${response.status}: ${detail}`);
      Object.assign(error, { status: response.status, detail, errors: (data && data.errors) || [] });
      throw error;
    }
    return { data, response };
  }

  function escapeHtml(s) {
    return String(s ?? "").replace(/[&<>"']/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;" })[c]);
  }

  return { bindTokenField, withToken, request, escapeHtml };
})();
