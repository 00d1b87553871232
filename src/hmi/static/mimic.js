// The P&ID mimic: the server's SVG (hmi.mimic, from /api/site) inserted into #mimic and animated
// from the store through its bindings and data-* attributes (hmi/mimic.py's docstring):
//   level   water height = data-span * clamp(v / data-full, 0, 1), anchored at data-bottom
//   pump    running (command > 0) drawn darker grey; command and flow written next to it
//   opening valve drawn closed (dark) / open (light), the opening written in %
//   leak, fault, trip   marked (coloured) while not 0 / NONE / false
//   mode, sp, pv        written below the controller bubble
// ISA-101: everything stays grey; colour only for the abnormal (leak, fault, trip, bad quality)
// and for active alarms, by priority (data-alarm names the condition). A click (or Enter/Space)
// on an element with data-faceplate opens that faceplate.

import { fmt } from "./store.js";

const SVG_NS = "http://www.w3.org/2000/svg";
const PRIORITIES = ["URGENT", "HIGH", "MEDIUM", "LOW"];

export class Mimic {
  constructor(container, site, store, openFaceplate) {
    this.container = container;
    this.store = store;
    this.site = site;
    container.innerHTML = site.mimic.svg;
    this.svg = container.querySelector("svg");
    this.byTag = new Map(); // tag -> [{node, kind}]
    this.labels = new Map(); // element id -> <text> with its live values
    for (const b of site.mimic.bindings) {
      const node = this.svg.getElementById(b.element) || this.svg.querySelector(`[id="${b.element}"]`);
      if (!node) continue;
      if (!this.byTag.has(b.tag)) this.byTag.set(b.tag, []);
      this.byTag.get(b.tag).push({ node, kind: b.kind });
    }
    for (const node of this.svg.querySelectorAll("[data-faceplate]")) {
      node.setAttribute("tabindex", "0");
      node.setAttribute("role", "button");
      node.setAttribute("aria-label", `open faceplate ${node.dataset.faceplate}`);
      node.classList.add("clickable");
      node.addEventListener("click", () => openFaceplate(node.dataset.faceplate));
      node.addEventListener("keydown", (ev) => {
        if (ev.key === "Enter" || ev.key === " ") {
          ev.preventDefault();
          openFaceplate(node.dataset.faceplate);
        }
      });
    }
    store.listen((changed) => this.render(changed));
    this.render(new Set(this.byTag.keys()));
  }

  /** Redraw the elements bound to the ``changed`` paths. */
  render(changed) {
    const touched = new Set();
    for (const path of changed) {
      for (const { node, kind } of this.byTag.get(path) || []) {
        this.apply(node, kind, this.store.get(path));
        touched.add(node);
      }
    }
    for (const node of touched) this.writeLabel(node);
  }

  apply(node, kind, item) {
    const bad = item !== undefined && item.q !== "Good";
    const v = item?.v;
    switch (kind) {
      case "level": {
        const full = Number(node.dataset.full), bottom = Number(node.dataset.bottom), span = Number(node.dataset.span);
        const frac = typeof v === "number" && full > 0 ? Math.min(Math.max(v / full, 0), 1) : 0;
        node.setAttribute("height", (span * frac).toFixed(1));
        node.setAttribute("y", (bottom - span * frac).toFixed(1));
        node.classList.toggle("bad-quality", bad);
        break;
      }
      case "pump_command":
        node.classList.toggle("running", typeof v === "number" && v > 0);
        node.classList.toggle("bad-quality", bad);
        break;
      case "opening":
        node.classList.toggle("closed", typeof v === "number" && v <= 0);
        node.classList.toggle("bad-quality", bad);
        break;
      case "leak":
        node.classList.toggle("abnormal", typeof v === "number" && v > 0);
        break;
      case "fault":
        node.classList.toggle("abnormal", v !== undefined && v !== null && v !== "NONE" && v !== 0);
        break;
      case "trip":
        node.classList.toggle("abnormal", v === true);
        break;
      default:
        break;
    }
  }

  /** The live numbers written next to an element (its value label, created on first use). */
  writeLabel(node) {
    const id = node.id;
    const s = this.store;
    let text = null;
    const tagOf = (kind) => this.site.mimic.bindings.find((b) => b.element === id && b.kind === kind)?.tag;
    const val = (kind) => s.value(tagOf(kind));
    if (id.endsWith("-water")) text = `${fmt(val("level"), 3)} m`;
    else if (id.endsWith("-pump")) text = `Q ${fmt(val("pump_flow"), 3)} m³/s`;
    else if (id.endsWith("-valve")) {
      const o = val("opening");
      text = typeof o === "number" ? `${Math.round(o * 100)} %` : "—";
    } else if (id.endsWith("-bubble") && tagOf("mode")) {
      text = `${val("mode") ?? "—"} PV ${fmt(val("pv"), 3)} SP ${fmt(val("sp"), 3)}`;
    } else if (id.endsWith("-bubble") && tagOf("fault")) {
      const f = val("fault");
      text = f && f !== "NONE" ? `${fmt(val("pv"), 3)} m ${f}` : `${fmt(val("pv"), 3)} m`;
    }
    if (text === null) return;
    let label = this.labels.get(id);
    if (!label) {
      label = document.createElementNS(SVG_NS, "text");
      label.setAttribute("class", "value");
      label.dataset.valueOf = id;
      const box = node.getBBox();
      let x = box.x + box.width / 2, y = box.y + box.height + 14;
      if (id.endsWith("-water")) {
        const vessel = this.svg.getElementById(id.replace("-water", "-vessel"));
        const vb = vessel ? vessel.getBBox() : box;
        x = vb.x + vb.width / 2;
        y = vb.y + vb.height / 2;
      } else if (id.endsWith("-bubble") && tagOf("mode")) {
        y = box.y - 6;
      } else if (id.endsWith("-valve")) {
        y = box.y + box.height + 12;
      }
      label.setAttribute("x", x.toFixed(1));
      label.setAttribute("y", y.toFixed(1));
      this.svg.append(label);
      this.labels.set(id, label);
    }
    label.textContent = text;
  }

  /** Colour the elements whose data-alarm condition is active (or unacked), by priority. */
  showAlarms(alarms) {
    const worst = new Map(); // condition name -> alarm
    for (const a of alarms) {
      if (!(a.active || !a.acked) || a.shelved !== "Unshelved" || a.enabled === false) continue;
      const prev = worst.get(a.condition);
      if (!prev || PRIORITIES.indexOf(a.priority) < PRIORITIES.indexOf(prev.priority)) worst.set(a.condition, a);
    }
    for (const node of this.svg.querySelectorAll("[data-alarm]")) {
      for (const p of PRIORITIES) node.classList.remove(`alarm-${p.toLowerCase()}`);
      node.classList.remove("alarm-unacked");
      const a = worst.get(node.dataset.alarm);
      if (!a) continue;
      node.classList.add(`alarm-${String(a.priority).toLowerCase()}`);
      if (!a.acked) node.classList.add("alarm-unacked");
    }
  }
}
