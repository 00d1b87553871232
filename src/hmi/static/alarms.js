// Alarms: the banner (#alarm-banner: the highest-priority unacknowledged alarm, URGENT > HIGH >
// MEDIUM > LOW, then severity, then the newest), the list of current conditions (#alarm-list,
// one tr[data-alarm-id] each: priority, time, state, message; acknowledge or confirm with a
// comment, shelve one-shot or timed, unshelve) and the alarm history from the historian
// (/api/alarms/history). The list is the websocket's "alarms" message, the whole list each time;
// a comment being typed survives the re-render.

import { command, getJson, query } from "./api.js";
import { el } from "./store.js";

const ORDER = { URGENT: 0, HIGH: 1, MEDIUM: 2, LOW: 3 };

function rank(a, b) {
  return (ORDER[a.priority] ?? 9) - (ORDER[b.priority] ?? 9) || b.severity - a.severity || b.time - a.time;
}

function when(t) {
  return typeof t === "number" ? new Date(t * 1000).toISOString().replace("T", " ").slice(0, 19) : "—";
}

/** The state column: ISA-18.2's words for active/acknowledged/shelved. */
export function stateText(a) {
  const parts = [a.active ? "ACTIVE" : "RTN", a.acked ? "ACKED" : "UNACKED"];
  if (a.acked && a.confirmed === false) parts.push("UNCONFIRMED");
  if (a.shelved && a.shelved !== "Unshelved") parts.push(a.shelved.toUpperCase());
  if (a.enabled === false) parts.push("DISABLED");
  return parts.join(" ");
}

export class Alarms {
  constructor(banner, list, historyRoot, session, hooks) {
    this.banner = banner;
    this.tbody = list.querySelector("tbody");
    this.status = document.getElementById("alarm-status");
    this.session = session;
    this.hooks = hooks; // {openFaceplate(key), changed(alarms)}
    this.alarms = [];
    this.drafts = new Map(); // alarm id -> comment being typed
    this.historyRoot = historyRoot;
    // assigned, not added: the banner and the history button outlive a login
    historyRoot.querySelector("[data-action=alarm-history]").onclick = () => this.loadHistory();
    banner.onclick = () => this.focusTop();
    banner.onkeydown = (ev) => {
      if (ev.key === "Enter") this.focusTop();
    };
    this.render();
  }

  set(alarms) {
    this.alarms = Array.isArray(alarms) ? [...alarms].sort(rank) : [];
    this.render();
    this.hooks.changed(this.alarms);
  }

  top() {
    return this.alarms.find((a) => !a.acked && a.enabled !== false && (a.shelved ?? "Unshelved") === "Unshelved");
  }

  render() {
    const top = this.top();
    const unacked = this.alarms.filter((a) => !a.acked).length;
    for (const p of Object.keys(ORDER)) this.banner.classList.remove(`prio-${p.toLowerCase()}`);
    if (top) {
      this.banner.classList.add(`prio-${String(top.priority).toLowerCase()}`);
      this.banner.dataset.alarmId = top.id;
      this.banner.textContent = `${top.priority} ${top.condition} (${top.source}): ${top.message} — ${when(top.time)}` + (unacked > 1 ? ` (+${unacked - 1} more unacknowledged)` : "");
      this.banner.tabIndex = 0;
    } else {
      delete this.banner.dataset.alarmId;
      this.banner.textContent = this.alarms.length ? `no unacknowledged alarms (${this.alarms.length} in the list)` : "no alarms";
      this.banner.removeAttribute("tabindex");
    }
    const focus = document.activeElement;
    const focusRow = focus?.closest?.("tr[data-alarm-id]")?.dataset.alarmId;
    const focusField = focus?.dataset?.field || focus?.dataset?.action;
    const readOnly = this.session.role === "Observer";
    const rows = this.alarms.map((a) => this.row(a, readOnly));
    this.tbody.replaceChildren(...rows);
    if (!rows.length) this.tbody.append(el("tr", { class: "empty" }, el("td", { colspan: 8, text: "no active or unacknowledged alarms" })));
    if (focusRow && focusField) {
      const sel = `tr[data-alarm-id="${CSS.escape(focusRow)}"] [data-field="${focusField}"], tr[data-alarm-id="${CSS.escape(focusRow)}"] [data-action="${focusField}"]`;
      this.tbody.querySelector(sel)?.focus();
    }
  }

  row(a, readOnly) {
    const cid = `comment-${a.id.replace(/[^A-Za-z0-9_-]/g, "_")}`;
    const comment = el("input", { id: cid, dataset: { field: "comment" }, placeholder: "comment", "aria-label": `comment for ${a.id}`, disabled: readOnly, value: this.drafts.get(a.id) ?? "" });
    comment.addEventListener("input", () => this.drafts.set(a.id, comment.value));
    const verb = (action, text, send, enabled = true) => el("button", { type: "button", dataset: { action }, disabled: readOnly || !enabled, onclick: send }, text);
    const shelveKind = el("select", { dataset: { field: "shelve-kind" }, "aria-label": `shelve ${a.id}`, disabled: readOnly },
      el("option", { value: "oneshot", text: "one-shot" }), el("option", { value: "timed", text: "10 min" }));
    const shelved = a.shelved && a.shelved !== "Unshelved";
    const actions = el("td", { class: "actions" },
      verb("ack", "Ack", () => this.send("ack", a, { comment: comment.value }), !a.acked),
      verb("confirm", "Confirm", () => this.send("confirm", a, { comment: comment.value }), a.acked && a.confirmed === false),
      verb("comment", "Comment", () => this.send("comment", a, { comment: comment.value })),
      shelved ? verb("unshelve", "Unshelve", () => this.send("shelve", a, { kind: "unshelve" }))
        : el("span", {}, shelveKind, verb("shelve", "Shelve", () => this.send("shelve", a, { kind: shelveKind.value, duration_s: 600 }))));
    const tr = el("tr", { class: `prio-${String(a.priority).toLowerCase()}${a.acked ? " acked" : " unacked"}${a.active ? " active" : ""}`, dataset: { alarmId: a.id, acked: String(a.acked), active: String(a.active) } },
      el("td", { class: "prio", text: a.priority }),
      el("td", { text: when(a.time) }),
      el("td", {}, el("button", { type: "button", class: "link", dataset: { action: "goto" }, onclick: () => this.goto(a) }, a.source)),
      el("td", { text: a.condition }),
      el("td", { dataset: { field: "state" }, text: stateText(a) }),
      el("td", { text: a.message }),
      el("td", {}, a.comment ? el("div", { class: "last-comment", dataset: { field: "last-comment" }, text: a.comment }) : null, comment),
      actions);
    return tr;
  }

  async send(verb, a, extra) {
    const res = await command(`/api/alarms/${verb}`, { id: a.id, ...extra });
    this.status.textContent = `${verb} ${a.id}: ${res.text}`;
    this.status.classList.toggle("refused", !res.ok);
    if (res.ok) this.drafts.delete(a.id);
  }

  /** Open the faceplate of an alarm's source: a loop (LIC1), a transmitter (LT1: its tank's), a
   * tank (T1), bare or as a path (PLC.LIC1, PLC.IO.LT1, PLC.T1); the supervisor's otherwise. */
  goto(a) {
    const m = /(?:^|\.)(LIC\d+|LT(\d+)|T\d+)(?:$|\.)/.exec(a.source || "");
    if (m && m[2]) this.hooks.openFaceplate(`tank:T${m[2]}`);
    else if (m) this.hooks.openFaceplate(m[1].startsWith("LIC") ? `loop:${m[1]}` : `tank:${m[1]}`);
    else if (a.tier === "supervisor") this.hooks.openFaceplate("supervisor");
  }

  focusTop() {
    const id = this.banner.dataset.alarmId;
    if (id) this.tbody.querySelector(`tr[data-alarm-id="${CSS.escape(id)}"] [data-field=comment]`)?.focus();
  }

  async loadHistory() {
    const range = Number(this.historyRoot.querySelector("#alarm-history-range").value);
    const end = Date.now() / 1000;
    const out = this.historyRoot.querySelector("#alarm-history-status");
    out.textContent = "loading…";
    const { status, body } = await getJson(`/api/alarms/history?${query({ start: (end - range).toFixed(3), end: end.toFixed(3), limit: 500 })}`);
    const tbody = document.querySelector("#alarm-history tbody");
    if (status !== 200) {
      out.textContent = `alarm history not available: ${body.error || `HTTP ${status}`}`;
      return;
    }
    const events = body.events || [];
    out.textContent = `${events.length} event(s)`;
    tbody.replaceChildren(...events.map((e) => el("tr", { dataset: { event: e.event } },
      el("td", { text: when(e.time) }), el("td", { text: e.tier }), el("td", { text: e.source }), el("td", { text: e.condition }),
      el("td", { text: e.event }), el("td", { text: String(e.severity ?? "") }), el("td", { text: e.message }))));
  }
}
