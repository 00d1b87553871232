// Faceplates: the detail and command panel of one mimic element, opened into #faceplate.
//   loop:LIC1   PV/SP/MV bars, SP entry (range-checked here, the tier's status shown on refusal),
//               mode MANUAL/AUTO/REMOTE, manual MV [% of the MV's EURange], gains and their
//               source, reset to the baseline gains (Engineer)
//   tank:T1     level, transmitter reading and fault, leak opening 0..1 and disturbance [m^3/s]
//               (simulation control, Operator), the high-high interlock and its reset
//   pump:P1     command and flow, the loop that drives it
//   valve:V12   opening 0..1
//   supervisor  mode, MPC status, solve time, PredictedPV and PlannedMV over the horizon (uPlot)
// Every control that changes the process carries data-write (disabled for Observer); the
// Engineer-only ones data-engineer too. The server and the tier check roles anyway.

import { command } from "./api.js";
import { el, fmt } from "./store.js";

const MODES = ["MANUAL", "AUTO", "REMOTE"];
const SUPERVISOR_MODES = ["OFF", "ADVISORY", "ADAPTIVE_PID", "MPC"];
const FAULTS = ["NONE", "BIAS", "STUCK", "DRIFT"];
/** Axis ticks of flows (1e-5 m^3/s): in scientific notation, not rounded to 0. */
const sci = (u, splits) => splits.map((v) => (v === 0 ? "0" : v.toExponential(1)));

export class Faceplates {
  constructor(container, site, store, session, hooks) {
    this.box = container;
    this.site = site;
    this.store = store;
    this.session = session;
    this.hooks = hooks; // {trend(paths)}
    this.current = null; // {key, update()}
    this.unlisten = store.listen((changed) => this.current?.update(changed));
  }

  /** Open the faceplate ``key`` ("loop:LIC1", "tank:T1", "pump:P1", "valve:V12", "supervisor"). */
  open(key) {
    const [kind, name] = key.split(":");
    this.close();
    const builders = { loop: this.loop, tank: this.tank, pump: this.pump, valve: this.valve, supervisor: this.supervisor };
    const build = builders[kind];
    if (!build) return;
    this.box.replaceChildren();
    this.box.dataset.faceplate = key;
    const closeBtn = el("button", { type: "button", dataset: { action: "close-faceplate" }, "aria-label": "Close faceplate", onclick: () => this.close() }, "×");
    const body = el("div", { class: "fp-body" });
    this.box.append(el("div", { class: "fp-head" }, el("h2", { text: kind === "supervisor" ? "Supervisor" : name }), closeBtn), body);
    this.current = { key, update: () => {}, dispose: () => {} };
    build.call(this, body, name);
    this.applyRole();
    this.box.hidden = false;
    this.current.update(null);
    this.box.querySelector("input, select, button:not([data-action=close-faceplate])")?.focus();
  }

  close() {
    this.current?.dispose();
    this.current = null;
    this.box.hidden = true;
    this.box.replaceChildren();
    delete this.box.dataset.faceplate;
  }

  applyRole() {
    const role = this.session.role;
    for (const node of this.box.querySelectorAll("[data-write]")) {
      const allowed = role !== "Observer" && (!node.hasAttribute("data-engineer") || role === "Engineer");
      node.disabled = !allowed;
      if (!allowed) node.title = role === "Observer" ? "Observer: read only" : "Engineer only";
    }
  }

  // ---- shared parts ------------------------------------------------------------------------

  /** A read-only value row; returns the function that refreshes it. */
  row(parent, label, path, unit = "", digits = 4) {
    const out = el("output", { dataset: { path } });
    parent.append(el("div", { class: "fp-row" }, el("span", { class: "fp-label", text: label }), out, unit ? el("span", { class: "unit", text: unit }) : null));
    return () => {
      const item = this.store.get(path);
      out.textContent = item ? fmt(item.v, digits) : "—";
      out.classList.toggle("bad-quality", item !== undefined && item.q !== "Good");
      out.title = item ? `${path}: ${item.q}` : path;
    };
  }

  /** A horizontal bar of ``path`` over [lo, hi]. */
  bar(parent, label, path, lo, hi, unit) {
    const fill = el("div", { class: "bar-fill" });
    const value = el("span", { class: "bar-value" });
    parent.append(el("div", { class: "fp-bar", dataset: { bar: label } }, el("span", { class: "fp-label", text: label }), el("div", { class: "bar", role: "img", "aria-label": `${label} bar` }, fill), value));
    return () => {
      const item = this.store.get(path);
      const v = item?.v;
      const frac = typeof v === "number" && hi > lo ? Math.min(Math.max((v - lo) / (hi - lo), 0), 1) : 0;
      fill.style.width = `${(frac * 100).toFixed(1)}%`;
      value.textContent = `${fmt(v, 4)} ${unit}`;
      fill.classList.toggle("bad-quality", item !== undefined && item.q !== "Good");
    };
  }

  /** The line that shows the last command's outcome ([data-field=status]). */
  statusLine(parent) {
    const line = el("p", { class: "fp-status", role: "status", dataset: { field: "status" } });
    parent.append(line);
    return (ok, text) => {
      line.textContent = text;
      line.classList.toggle("refused", !ok);
      line.classList.toggle("accepted", ok);
    };
  }

  /** A number entry with its apply button; ``check(value)`` returns an error text or null. */
  entry(parent, { label, field, action, step, min, max, unit, check, send, show }) {
    const id = `fp-${field}`;
    const input = el("input", { id, type: "number", step, min, max, inputmode: "decimal", dataset: { field }, "data-write": true });
    const button = el("button", { type: "button", dataset: { action }, "data-write": true }, "Apply");
    const form = el("form", { class: "fp-entry" }, el("label", { for: id, text: label }), input, unit ? el("span", { class: "unit", text: unit }) : null, button);
    const submit = async (ev) => {
      ev?.preventDefault();
      const raw = input.value.trim();
      const value = Number(raw);
      const problem = raw === "" || !Number.isFinite(value) ? `not a number: '${raw}'` : check(value);
      if (problem) {
        show(false, `not sent: ${problem}`);
        input.setAttribute("aria-invalid", "true");
        return;
      }
      input.removeAttribute("aria-invalid");
      button.disabled = true;
      const res = await send(value);
      button.disabled = false;
      this.applyRole();
      show(res.ok, res.text);
    };
    form.addEventListener("submit", submit);
    button.addEventListener("click", submit);
    parent.append(form);
    return input;
  }

  /** A select of enumeration names written to ``path`` on Apply. */
  choice(parent, { label, field, action, options, path, show }) {
    const id = `fp-${field}`;
    const select = el("select", { id, dataset: { field }, "data-write": true }, ...options.map((o) => el("option", { value: o, text: o })));
    const button = el("button", { type: "button", dataset: { action }, "data-write": true }, "Apply");
    let touched = false;
    select.addEventListener("change", () => { touched = true; });
    button.addEventListener("click", async () => {
      const res = await command("/api/write", { path, value: select.value });
      touched = false;
      show(res.ok, res.text);
    });
    parent.append(el("div", { class: "fp-entry" }, el("label", { for: id, text: label }), select, button));
    return () => {
      const v = this.store.value(path);
      if (!touched && document.activeElement !== select && typeof v === "string") select.value = v;
    };
  }

  // ---- the faceplates ------------------------------------------------------------------------

  loop(body, name) {
    const lp = this.site.loops.find((l) => l.name === name);
    if (!lp) return;
    const p = (leaf) => `PLC.${name}.${leaf}`;
    const [spLo, spHi] = lp.sp_range_m;
    const [mvLo, mvHi] = lp.mv_range;
    const tank = this.site.tanks.find((t) => t.name === lp.pv_tank);
    const levelHi = tank ? tank.height_max_m : spHi;
    body.append(el("p", { class: "fp-note", text: `PV ${lp.pv_tank}, MV ${lp.pump} [${lp.mv_unit}]` }));
    const show = this.statusLine(body);
    const ups = [
      this.bar(body, "PV", p("PV"), 0, levelHi, "m"),
      this.bar(body, "SP", p("SP"), 0, levelHi, "m"),
      this.bar(body, "MV", p("MV"), mvLo, mvHi, lp.mv_unit),
      this.row(body, "Mode", p("Mode")),
    ];
    this.entry(body, {
      label: "SP", field: "sp-input", action: "sp-apply", step: "0.001", min: spLo, max: spHi, unit: "m",
      check: (v) => (v < spLo || v > spHi ? `SP ${v} m outside [${spLo}, ${spHi}] m` : null),
      send: (v) => command("/api/write", { path: p("SP"), value: v }),
      show,
    });
    ups.push(this.choice(body, { label: "Mode", field: "mode", action: "mode-apply", options: MODES, path: p("Mode"), show }));
    this.entry(body, {
      label: "Manual MV", field: "manual-input", action: "manual-apply", step: "1", min: 0, max: 100, unit: "%",
      check: (v) => (v < 0 || v > 100 ? `manual MV ${v} % outside [0, 100] %` : null),
      send: (v) => command(`/api/loop/${encodeURIComponent(name)}/manual`, { percent: v }),
      show,
    });
    ups.push(this.row(body, "ManualMV", p("ManualMV"), lp.mv_unit), this.row(body, "RemoteMV", p("RemoteMV"), lp.mv_unit));
    const gains = el("fieldset", { class: "fp-gains" }, el("legend", { text: "Gains" }));
    body.append(gains);
    if (lp.has_gains) {
      ups.push(this.row(gains, "Kp", p("Kp")), this.row(gains, "Ki", p("Ki")), this.row(gains, "Kd", p("Kd")), this.row(gains, "Source", p("GainSource")));
      const reset = el("button", { type: "button", dataset: { action: "reset-gains" }, "data-write": true, "data-engineer": true }, "Reset to baseline gains");
      reset.addEventListener("click", async () => {
        const res = await command(`/api/loop/${encodeURIComponent(name)}/reset-gains`, {});
        show(res.ok, res.text);
      });
      gains.append(reset);
    } else {
      gains.append(el("p", { class: "fp-note", text: "this loop's block has no PID gains" }));
    }
    body.append(el("button", { type: "button", dataset: { action: "trend-loop" }, onclick: () => this.hooks.trend([p("PV"), p("SP"), p("MV")]) }, "Trend PV, SP, MV"));
    this.current.update = () => ups.forEach((u) => u());
  }

  tank(body, name) {
    const tp = (leaf) => `Plant.${name}.${leaf}`;
    const lt = `LT${name.slice(1)}`;
    const tank = this.site.tanks.find((t) => t.name === name);
    const show = this.statusLine(body);
    const ups = [
      this.bar(body, "Level", tp("Level"), 0, tank ? tank.height_max_m : 1, "m"),
      this.row(body, `${lt} PV`, `Plant.${lt}.PV`, "m"),
      this.row(body, "Leak", tp("Leak")),
      this.row(body, "Disturbance", tp("Disturbance"), "m³/s"),
    ];
    this.entry(body, {
      label: "Leak opening", field: "leak-input", action: "leak-apply", step: "0.01", min: 0, max: 1, unit: "0..1",
      check: (v) => (v < 0 || v > 1 ? `leak opening ${v} outside [0, 1]` : null),
      send: (v) => command("/api/write", { path: tp("Leak"), value: v }),
      show,
    });
    this.entry(body, {
      label: "Disturbance", field: "disturbance-input", action: "disturbance-apply", step: "any", unit: "m³/s",
      check: () => null, // its range is the plant's (disturbance_limit_m3_s): the tier says BadOutOfRange
      send: (v) => command("/api/write", { path: tp("Disturbance"), value: v }),
      show,
    });
    ups.push(this.choice(body, { label: `${lt} fault`, field: "fault", action: "fault-apply", options: FAULTS, path: `Plant.${lt}.Fault`, show }));
    const trip = `PLC.Interlock.${name}HH`;
    if (this.store.get(trip) !== undefined) {
      ups.push(this.row(body, "HH trip", trip));
      const reset = el("button", { type: "button", dataset: { action: "interlock-reset" }, "data-write": true }, "Reset interlocks");
      reset.addEventListener("click", async () => {
        const res = await command("/api/interlock/reset", {});
        show(res.ok, res.text);
      });
      body.append(reset);
    }
    body.append(el("button", { type: "button", dataset: { action: "trend-tank" }, onclick: () => this.hooks.trend([tp("Level"), `Plant.${lt}.PV`]) }, "Trend level"));
    this.current.update = () => ups.forEach((u) => u());
  }

  pump(body, name) {
    const pump = this.site.pumps.find((x) => x.name === name);
    const ups = [
      this.row(body, "Command", `Plant.${name}.Command`, pump?.unit || ""),
      this.row(body, "Flow", `Plant.${name}.Flow`, "m³/s"),
    ];
    for (const lp of this.site.loops.filter((l) => l.pump === name)) {
      body.append(el("button", { type: "button", dataset: { action: "open-loop" }, onclick: () => this.open(`loop:${lp.name}`) }, `Open ${lp.name}`));
    }
    this.current.update = () => ups.forEach((u) => u());
  }

  valve(body, name) {
    const path = `Plant.${name}.Opening`;
    const show = this.statusLine(body);
    const ups = [this.row(body, "Opening", path)];
    this.entry(body, {
      label: "Opening", field: "opening-input", action: "opening-apply", step: "0.01", min: 0, max: 1, unit: "0..1",
      check: (v) => (v < 0 || v > 1 ? `opening ${v} outside [0, 1]` : null),
      send: (v) => command("/api/write", { path, value: v }),
      show,
    });
    this.current.update = () => ups.forEach((u) => u());
  }

  supervisor(body) {
    const show = this.statusLine(body);
    const ups = [
      this.row(body, "Mode", "Supervisor.Mode"),
      this.row(body, "MPC status", "Supervisor.MPC.Status"),
      this.row(body, "Solve time", "Supervisor.MPC.SolveTime", "s"),
      this.row(body, "Horizon", "Supervisor.MPC.Horizon", "steps"),
    ];
    ups.push(this.choice(body, { label: "Mode", field: "supervisor-mode", action: "supervisor-mode-apply", options: SUPERVISOR_MODES, path: "Supervisor.Mode", show }));
    const chartBox = el("div", { id: "mpc-plan", class: "fp-chart" });
    body.append(el("p", { class: "fp-note", text: "MPC plan over the horizon (step k)" }), chartBox);
    let chart = null;
    let lastKey = "";
    const draw = () => {
      const pv = this.store.value("Supervisor.MPC.PredictedPV");
      const mv = this.store.value("Supervisor.MPC.PlannedMV");
      const np = Number(this.store.value("Supervisor.MPC.Horizon"));
      if (!Array.isArray(pv) || !Array.isArray(mv) || !(np > 0)) return;
      const key = JSON.stringify([pv, mv, np]);
      if (key === lastKey) return;
      lastKey = key;
      const nz = Math.max(1, Math.round(pv.length / np));
      const nu = Math.max(1, Math.round(mv.length / np));
      const steps = Array.from({ length: np }, (_, k) => k + 1);
      const data = [steps];
      const series = [{ label: "k" }];
      const levelNames = this.site.loops.map((l) => l.pv_tank);
      for (let j = 0; j < nz; j++) {
        data.push(steps.map((_, k) => pv[k * nz + j] ?? null));
        series.push({ label: `PredictedPV ${levelNames[j] || j + 1} [m]`, scale: "m", stroke: ["#1f4e79", "#2e75b6", "#5b9bd5"][j % 3], width: 2 });
      }
      for (let j = 0; j < nu; j++) {
        data.push(steps.map((_, k) => mv[k * nu + j] ?? null));
        series.push({ label: `PlannedMV ${this.site.pumps[j]?.name || j + 1} [m³/s]`, scale: "q", stroke: ["#7f6000", "#bf9000", "#a5a5a5"][j % 3], width: 1.5, dash: [6, 3] });
      }
      if (chart && chart.series.length !== series.length) {
        chart.destroy();
        chart = null;
      }
      if (!chart) {
        chart = new uPlot({
          width: Math.max(260, chartBox.clientWidth || 320), height: 200, series,
          scales: { x: { time: false } },
          legend: { live: false },
          axes: [{ label: "k" }, { scale: "m", label: "m" }, { scale: "q", side: 1, label: "m³/s", size: 64, values: sci, grid: { show: false } }],
        }, data, chartBox);
      } else {
        chart.setData(data);
      }
    };
    ups.push(draw);
    this.current.update = () => ups.forEach((u) => u());
    this.current.dispose = () => chart?.destroy();
  }
}
