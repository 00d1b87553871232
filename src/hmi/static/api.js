// The HMI server's HTTP API (HMI contract v1): JSON in and out, the session's CSRF token on
// every POST. Each call resolves to {status, body}; it never throws for an HTTP status, only for
// a network failure (then status is 0 and body.error says why).

let csrfToken = null;
let onUnauthorized = () => {};

/** Remember the session's CSRF token (from /api/session or /api/login). */
export function setCsrf(token) {
  csrfToken = token;
}

/** Called with no argument when a request answers 401 (session closed or expired). */
export function setUnauthorizedHandler(fn) {
  onUnauthorized = fn;
}

async function request(method, url, body) {
  const headers = { Accept: "application/json" };
  const init = { method, headers, credentials: "same-origin" };
  if (body !== undefined) {
    headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  if (method !== "GET" && csrfToken) headers["X-CSRF-Token"] = csrfToken;
  let resp;
  try {
    resp = await fetch(url, init);
  } catch (err) {
    return { status: 0, body: { error: `HMI server not reachable (${err.message})` } };
  }
  let parsed = null;
  const text = await resp.text();
  if (text) {
    try {
      parsed = JSON.parse(text);
    } catch {
      parsed = { error: text.slice(0, 200) };
    }
  }
  if (resp.status === 401 && url !== "/api/login" && url !== "/api/session") onUnauthorized();
  return { status: resp.status, body: parsed ?? {} };
}

export const getJson = (url) => request("GET", url);
export const postJson = (url, body = {}) => request("POST", url, body);

/**
 * A command (write, manual MV, reset gains, alarm verbs): the one-line outcome to show.
 * Returns {ok, text}: text is the tier's status code name ("Good", "BadOutOfRange: ...") or the
 * HTTP error.
 */
export async function command(url, body) {
  const { status, body: answer } = await postJson(url, body);
  if (status === 200 && answer.ok) return { ok: true, text: answer.status || "Good" };
  if (status === 200) {
    const detail = answer.error ? `: ${answer.error}` : "";
    return { ok: false, text: `${answer.status || "Bad"}${detail}` };
  }
  return { ok: false, text: `HTTP ${status || "error"}: ${answer.error || "request failed"}` };
}

/** Query string of repeated keys: query({path: ["a", "b"], start: 1}) -> "path=a&path=b&start=1". */
export function query(params) {
  const q = new URLSearchParams();
  for (const [key, value] of Object.entries(params)) {
    for (const v of Array.isArray(value) ? value : [value]) q.append(key, String(v));
  }
  return q.toString();
}
