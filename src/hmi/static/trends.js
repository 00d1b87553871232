// The trend (#trend, uPlot): any set of contract paths, historical from /api/trend (the
// historian's HistoryRead) and live from the websocket's values. Values arrive only when they
// change, so every series is drawn sample-and-hold: at each time stamp of the merged time axis
// a series shows its last value at or before it. Zoom: drag a range, or the +/- buttons; pan:
// the arrow buttons; either stops following the live edge until "Live". Paths in m share the
// left axis (SP and PV overlaid), flows (MV, commands, disturbances) the right one.
// Export: the shown range as CSV (time as epoch s and ISO, one column per path) and PNG.

import { getJson, query } from "./api.js";
import { el } from "./store.js";

const COLOURS = ["#1f4e79", "#c55a11", "#548235", "#7030a0", "#bf9000", "#2e75b6", "#a50021", "#3b3838"];
const FLOW_LEAVES = ["MV", "ManualMV", "RemoteMV", "Command", "Flow", "Disturbance"];
const MAX_POINTS = 20000;
const MAX_HISTORY_PATHS = 32;
const stepped = uPlot.paths.stepped({ align: 1 });

function scaleOf(path) {
  const leaf = path.split(".").pop();
  return FLOW_LEAVES.includes(leaf) ? "q" : "y";
}

export class Trend {
  constructor(root, store, hooks) {
    this.root = root; // the #trend-pane section
    this.box = root.querySelector("#trend");
    this.store = store;
    this.hooks = hooks; // {subscribe(paths)}
    this.paths = [];
    this.buffers = new Map(); // path -> {t: [], v: []}
    this.windowS = Number(root.querySelector("#trend-window").value);
    this.following = true;
    this.view = null; // {min, max} when not following
    this.chart = null;
    this.dirty = false;
    this.status = root.querySelector("#trend-status");
    this.picker = root.querySelector("#trend-tags");
    store.listen((changed) => this.onValues(changed));
    // the controls outlive a login: their handlers are assigned (not added), so the trend of
    // the session before a logout never answers them again
    root.querySelector("[data-action=trend-apply]").onclick = () => this.applyPicker();
    root.querySelector("#trend-add").onkeydown = (ev) => {
      if (ev.key === "Enter") this.applyPicker();
    };
    root.querySelector("#trend-window").onchange = (ev) => {
      this.windowS = Number(ev.target.value);
      this.load();
    };
    const on = (action, fn) => {
      root.querySelector(`[data-action=${action}]`).onclick = fn;
    };
    on("trend-pan-left", () => this.pan(-0.5));
    on("trend-pan-right", () => this.pan(0.5));
    on("trend-zoom-in", () => this.zoom(0.5));
    on("trend-zoom-out", () => this.zoom(2));
    on("trend-live", () => this.live());
    on("export-csv", () => this.exportCsv());
    on("export-png", () => this.exportPng());
    this.timer = setInterval(() => this.redraw(), 500);
    this.resize = new ResizeObserver(() => this.chart?.setSize(this.size()));
    this.resize.observe(this.box);
  }

  dispose() {
    clearInterval(this.timer);
    this.resize.disconnect();
    this.chart?.destroy();
    this.chart = null;
    this.paths = [];
  }

  /** Offer ``paths`` in the picker (the ones the store knows). */
  offer(paths) {
    const known = [...new Set(paths)].sort();
    const selected = new Set(this.paths);
    this.picker.replaceChildren(...known.map((p) => el("option", { value: p, text: p, selected: selected.has(p) })));
    this.root.querySelector("#trend-known").replaceChildren(...known.map((p) => el("option", { value: p })));
  }

  applyPicker() {
    const chosen = [...this.picker.selectedOptions].map((o) => o.value);
    const add = this.root.querySelector("#trend-add");
    const extra = add.value.split(/[\s,]+/).filter(Boolean);
    add.value = "";
    this.show([...chosen, ...extra]);
  }

  /** Trend exactly ``paths`` (history of the range loaded, live from now on). */
  show(paths) {
    this.paths = [...new Set(paths)];
    for (const option of this.picker.options) option.selected = this.paths.includes(option.value);
    for (const p of this.paths) if (![...this.picker.options].some((o) => o.value === p)) this.picker.append(el("option", { value: p, text: p, selected: true }));
    this.hooks.subscribe(this.paths);
    this.chart?.destroy();
    this.chart = null;
    this.root.dataset.paths = this.paths.join(" ");
    this.load();
  }

  range() {
    if (!this.following && this.view) return this.view;
    const now = Date.now() / 1000;
    return { min: now - this.windowS, max: now };
  }

  /** Fetch the historian's record of the shown range and merge it under the live values. */
  async load() {
    const paths = this.paths;
    if (!paths.length) return;
    const { min, max } = this.range();
    this.status.textContent = "loading history…";
    // the server reads the history of at most MAX_HISTORY_PATHS paths at once (HMI contract notes)
    const asked = paths.slice(0, MAX_HISTORY_PATHS);
    const { status, body } = await getJson(`/api/trend?${query({ path: asked, start: min.toFixed(3), end: max.toFixed(3), points: 2000 })}`);
    if (paths !== this.paths) return;
    if (status !== 200) {
      this.status.textContent = `history not available: ${body.error || `HTTP ${status}`} (live values only)`;
      for (const p of paths) if (!this.buffers.has(p)) this.buffers.set(p, { t: [], v: [] });
    } else {
      const notes = [];
      if (body.aggregate) notes.push(`history: ${body.aggregate}`);
      if (asked.length < paths.length) notes.push(`history of the first ${asked.length} tags only`);
      this.status.textContent = notes.join("; ");
      for (const p of paths) {
        const hist = body.series?.[p] || { t: [], v: [] };
        const live = this.buffers.get(p) || { t: [], v: [] };
        const last = hist.t.length ? hist.t[hist.t.length - 1] : -Infinity;
        const t = [...hist.t], v = [...hist.v];
        live.t.forEach((ti, k) => {
          if (ti > last) {
            t.push(ti);
            v.push(live.v[k]);
          }
        });
        this.buffers.set(p, { t, v });
      }
    }
    this.dirty = true;
    this.redraw();
  }

  onValues(changed) {
    for (const p of this.paths) {
      if (!changed.has(p)) continue;
      const item = this.store.get(p);
      if (typeof item?.v !== "number" && typeof item?.v !== "boolean") continue;
      let buf = this.buffers.get(p);
      if (!buf) this.buffers.set(p, (buf = { t: [], v: [] }));
      const t = Number(item.t);
      if (buf.t.length && t <= buf.t[buf.t.length - 1]) continue;
      buf.t.push(t);
      buf.v.push(Number(item.v));
      if (buf.t.length > MAX_POINTS) {
        buf.t.splice(0, buf.t.length - MAX_POINTS);
        buf.v.splice(0, buf.v.length - MAX_POINTS);
      }
      this.dirty = true;
    }
  }

  /** The aligned data of uPlot: [times, series...], sample-and-hold, over every buffer. */
  aligned() {
    const times = [...new Set(this.paths.flatMap((p) => this.buffers.get(p)?.t || []))].sort((a, b) => a - b);
    const now = Date.now() / 1000;
    if (this.following && times.length && times[times.length - 1] < now) times.push(now); // hold to the live edge
    const data = [times];
    for (const p of this.paths) {
      const buf = this.buffers.get(p) || { t: [], v: [] };
      const col = new Array(times.length).fill(null);
      let k = -1;
      for (let i = 0; i < times.length; i++) {
        while (k + 1 < buf.t.length && buf.t[k + 1] <= times[i]) k++;
        col[i] = k >= 0 ? buf.v[k] : null;
      }
      data.push(col);
    }
    return data;
  }

  size() {
    return { width: Math.max(320, this.box.clientWidth || 800), height: 260 };
  }

  redraw() {
    if (!this.paths.length || (!this.dirty && !this.following)) return;
    this.dirty = false;
    const data = this.aligned();
    if (!this.chart) {
      const series = [{ label: "time" }, ...this.paths.map((p, k) => ({
        label: p, scale: scaleOf(p), stroke: COLOURS[k % COLOURS.length], width: p.endsWith(".SP") ? 1.5 : 2,
        dash: p.endsWith(".SP") ? [6, 4] : undefined, spanGaps: true,
        paths: stepped, // hold each value until the next one (never a ramp between two changes)
      }))];
      const axes = [{}, { scale: "y", label: "m" }];
      if (this.paths.some((p) => scaleOf(p) === "q")) axes.push({ scale: "q", side: 1, label: "m³/s", size: 64, values: (u, splits) => splits.map((v) => (v === 0 ? "0" : v.toExponential(1))), grid: { show: false } });
      const opts = {
        ...this.size(), series, axes,
        scales: { x: { time: true }, y: { auto: true }, q: { auto: true } },
        // a dragged range zooms (we set the scale: uPlot's own drag-zoom is off, so only the
        // user's selection, never a redraw, stops following the live edge)
        cursor: { drag: { x: true, y: false, setScale: false } },
        hooks: {
          setSelect: [(u) => {
            if (u.select.width < 3) return;
            const min = u.posToVal(u.select.left, "x"), max = u.posToVal(u.select.left + u.select.width, "x");
            u.setSelect({ left: 0, top: 0, width: 0, height: 0 }, false);
            this.view = { min, max };
            this.setFollowing(false);
            this.redraw();
          }],
        },
      };
      this.chart = new uPlot(opts, data, this.box);
    } else {
      this.chart.setData(data, false);
    }
    const { min, max } = this.range();
    this.chart.setScale("x", { min, max });
    this.root.dataset.points = String(data[0].length);
  }

  setFollowing(on) {
    this.following = on;
    this.root.querySelector("[data-action=trend-live]").setAttribute("aria-pressed", String(on));
    if (on) this.view = null;
    this.dirty = true;
  }

  pan(fraction) {
    const { min, max } = this.range();
    const d = (max - min) * fraction;
    this.view = { min: min + d, max: max + d };
    this.setFollowing(false);
    if (this.view.min < this.earliest()) this.load();
    else this.redraw();
  }

  zoom(factor) {
    const { min, max } = this.range();
    const mid = (min + max) / 2, half = ((max - min) * factor) / 2;
    this.view = { min: mid - half, max: mid + half };
    this.setFollowing(false);
    if (this.view.min < this.earliest()) this.load();
    else this.redraw();
  }

  live() {
    this.setFollowing(true);
    this.load();
  }

  earliest() {
    const firsts = this.paths.map((p) => this.buffers.get(p)?.t[0]).filter((t) => t !== undefined);
    return firsts.length ? Math.min(...firsts) : Infinity;
  }

  /** The shown rows: [epoch s, values...] inside the x range. */
  shownRows() {
    const data = this.aligned();
    const { min, max } = this.range();
    const rows = [];
    for (let i = 0; i < data[0].length; i++) {
      const t = data[0][i];
      if (t < min || t > max) continue;
      rows.push([t, ...data.slice(1).map((col) => col[i])]);
    }
    return rows;
  }

  csv() {
    const header = ["time_epoch_s", "time_utc", ...this.paths].join(",");
    const lines = this.shownRows().map(([t, ...vs]) => [t.toFixed(3), new Date(t * 1000).toISOString(), ...vs.map((v) => (v === null ? "" : String(v)))].join(","));
    return `${header}\n${lines.join("\n")}\n`;
  }

  fileStem() {
    const { min, max } = this.range();
    const iso = (t) => new Date(t * 1000).toISOString().replace(/[:.]/g, "-");
    return `trend_${iso(min)}_${iso(max)}`;
  }

  exportCsv() {
    if (!this.paths.length) return;
    download(new Blob([this.csv()], { type: "text/csv" }), `${this.fileStem()}.csv`);
    this.status.textContent = `exported ${this.shownRows().length} rows as CSV`;
  }

  exportPng() {
    if (!this.chart) return;
    const src = this.chart.ctx.canvas;
    const legend = 18 * this.paths.length + 10;
    const out = document.createElement("canvas");
    out.width = src.width;
    out.height = src.height + legend;
    const ctx = out.getContext("2d");
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, out.width, out.height);
    ctx.drawImage(src, 0, 0);
    ctx.font = "14px sans-serif";
    this.paths.forEach((p, k) => {
      ctx.fillStyle = COLOURS[k % COLOURS.length];
      ctx.fillRect(10, src.height + 8 + 18 * k, 12, 12);
      ctx.fillStyle = "#222";
      ctx.fillText(p, 28, src.height + 19 + 18 * k);
    });
    out.toBlob((blob) => {
      download(blob, `${this.fileStem()}.png`);
      this.status.textContent = "exported the shown trend as PNG";
    }, "image/png");
  }
}

function download(blob, name) {
  const url = URL.createObjectURL(blob);
  const a = el("a", { href: url, download: name, hidden: true });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}
