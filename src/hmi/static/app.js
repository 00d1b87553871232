// The HMI's entry point: the session (login form, /api/session, logout, 401 -> back to the
// login), the site (/api/site), the websocket /ws (values into the store, the alarm list, the
// tiers' link state; reconnect with a growing delay, 0.5 s to 8 s, until a logout or a 4401),
// and the wiring of the mimic, the faceplates, the trend and the alarms.

import { getJson, postJson, setCsrf, setUnauthorizedHandler } from "./api.js";
import { Alarms } from "./alarms.js";
import { Faceplates } from "./faceplates.js";
import { Mimic } from "./mimic.js";
import { Store, fmt } from "./store.js";
import { Trend } from "./trends.js";

const $ = (sel) => document.querySelector(sel);
const store = new Store();
let app = null; // the logged-in screen's parts

function showLogin(message = "") {
  teardown();
  document.body.dataset.state = "login";
  $("#main-view").hidden = true;
  $("#login-view").hidden = false;
  $("#login-error").textContent = message;
  $("#login-password").value = "";
  $("#login-user").focus();
}

function teardown() {
  if (!app) return;
  app.closing = true;
  app.socket?.close(1000, "logout");
  clearTimeout(app.retry);
  app.trend.dispose();
  app.faceplates.close();
  app = null;
  // nothing of the last session stays in the page
  for (const sel of ["#mimic", "#links", "#alarm-list tbody", "#alarm-history tbody", "#alarm-banner", "#trend-status", "#alarm-status"]) {
    $(sel).replaceChildren();
  }
  store.clear();
  store.listeners.clear();
  setCsrf(null);
}

async function start(session) {
  setCsrf(session.csrf);
  const { status, body: site } = await getJson("/api/site");
  if (status !== 200) {
    showLogin(status === 401 ? "" : `cannot load the site: ${site.error || `HTTP ${status}`}`);
    return;
  }
  document.body.dataset.role = session.role;
  $("#whoami").textContent = `${session.user} (${session.role})`;
  $("#site-name").textContent = site.site;
  document.title = `tanklab HMI: ${site.site}`;
  $("#login-view").hidden = true;
  $("#main-view").hidden = false;
  $("#open-supervisor").hidden = !site.supervisor;

  const parts = { session, site, closing: false, socket: null, retry: null, delay: 500, subscribed: new Set(), latency: [], seenValues: false };
  app = parts;
  window.tanklabHmi = { store, parts }; // for the browser's console
  parts.faceplates = new Faceplates($("#faceplate"), site, store, session, { trend: (paths) => parts.trend.show(paths) });
  const open = (key) => parts.faceplates.open(key);
  parts.mimic = new Mimic($("#mimic"), site, store, open);
  parts.trend = new Trend($("#trend-pane"), store, { subscribe: (paths) => subscribe(parts, paths) });
  parts.alarms = new Alarms($("#alarm-banner"), $("#alarm-list"), $("#alarms-pane"), session, {
    openFaceplate: open,
    changed: (alarms) => parts.mimic.showAlarms(alarms),
  });
  store.listen((changed) => {
    if (changed.has("Plant.Sim.Time")) $("#model-time").textContent = `model time ${fmt(store.value("Plant.Sim.Time"), 6)} s`;
  });
  let offered = 0;
  store.listen(() => {
    if (store.values.size !== offered) {
      offered = store.values.size;
      parts.trend.offer([...store.values.keys()].filter((p) => typeof store.value(p) === "number"));
    }
  });
  const first = site.loops[0];
  if (first) parts.trend.show([`PLC.${first.name}.PV`, `PLC.${first.name}.SP`]);
  connect(parts);
  document.body.dataset.state = "ready";
}

/** Seconds from each value's source timestamp to the end of the DOM update that showed it
 * (the latest 5000, for the browser's console and the latency benchmark). */
function recordLatency(samples, values) {
  const now = (performance.timeOrigin + performance.now()) / 1000;
  for (const item of Object.values(values)) if (typeof item?.t === "number") samples.push(now - item.t);
  if (samples.length > 5000) samples.splice(0, samples.length - 5000);
}

function subscribe(parts, paths) {
  const fresh = paths.filter((p) => !parts.subscribed.has(p));
  fresh.forEach((p) => parts.subscribed.add(p));
  if (fresh.length && parts.socket?.readyState === WebSocket.OPEN) parts.socket.send(JSON.stringify({ type: "subscribe", paths: fresh }));
}

function setLink(name, up, reason = "") {
  let badge = document.querySelector(`#links [data-link="${name}"]`);
  if (!badge) {
    badge = document.createElement("span");
    badge.dataset.link = name;
    badge.className = "link-badge";
    $("#links").append(badge);
  }
  badge.dataset.up = String(up);
  badge.textContent = up ? name : `${name} unreachable`;
  badge.title = reason || (up ? `${name}: connected` : `${name}: not connected`);
}

function connect(parts) {
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`;
  const socket = new WebSocket(url);
  parts.socket = socket;
  socket.addEventListener("open", () => {
    parts.delay = 500;
    setLink("hmi", true);
    if (parts.subscribed.size) socket.send(JSON.stringify({ type: "subscribe", paths: [...parts.subscribed] }));
  });
  socket.addEventListener("message", (ev) => {
    let msg;
    try {
      msg = JSON.parse(ev.data);
    } catch {
      return;
    }
    switch (msg.type) {
      case "hello":
        break;
      case "values": {
        const values = msg.values || {};
        store.update(values); // the views redraw synchronously
        if (parts.seenValues) recordLatency(parts.latency, values);
        parts.seenValues = true; // the first message carries every value, old ones too
        break;
      }
      case "alarms":
        parts.alarms.set(msg.alarms);
        break;
      case "link":
        setLink(msg.tier, Boolean(msg.up), msg.reason);
        break;
      case "error":
        $("#trend-status").textContent = msg.error;
        break;
      default:
        break;
    }
  });
  socket.addEventListener("close", (ev) => {
    if (parts.closing || app !== parts) return;
    if (ev.code === 4401) {
      showLogin("session closed: please log in again");
      return;
    }
    setLink("hmi", false, `websocket closed (${ev.code}); reconnecting`);
    parts.retry = setTimeout(() => connect(parts), parts.delay);
    parts.delay = Math.min(parts.delay * 2, 8000);
  });
}

$("#login-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const button = $("#login-submit");
  button.disabled = true;
  $("#login-error").textContent = "";
  const { status, body } = await postJson("/api/login", { user: $("#login-user").value, password: $("#login-password").value });
  button.disabled = false;
  if (status === 200) {
    $("#login-password").value = "";
    await start(body);
  } else {
    $("#login-error").textContent = body.error || `login failed (HTTP ${status})`;
    $("#login-password").select();
  }
});

$("#logout").addEventListener("click", async () => {
  await postJson("/api/logout", {});
  showLogin("logged out");
});

$("#open-supervisor").addEventListener("click", () => app?.faceplates.open("supervisor"));

setUnauthorizedHandler(() => showLogin("session expired: please log in again"));

(async () => {
  const { status, body } = await getJson("/api/session");
  if (status === 200) await start(body);
  else showLogin(status === 401 || status === 0 ? (status === 0 ? body.error : "") : `HTTP ${status}`);
})();
