// The live values by contract path, as the websocket delivers them: {v, q, t} per path
// (v: value, an enumeration as its name; q: "Good" or the status code name; t: source time,
// epoch s). Listeners hear the set of paths that changed with each batch.

export class Store {
  constructor() {
    this.values = new Map();
    this.listeners = new Set();
  }

  /** Merge a batch {path: {v, q, t}} and tell every listener which paths changed. */
  update(batch) {
    const changed = new Set();
    for (const [path, item] of Object.entries(batch)) {
      if (item === null || typeof item !== "object") continue;
      this.values.set(path, item);
      changed.add(path);
    }
    if (!changed.size) return;
    for (const fn of this.listeners) {
      try {
        fn(changed, this);
      } catch (err) {
        console.error("hmi: a view failed to show new values:", err); // the other views still update
      }
    }
  }

  /** {v, q, t} of ``path``, or undefined before its first value. */
  get(path) {
    return this.values.get(path);
  }

  /** The value of ``path`` (undefined before its first value). */
  value(path) {
    return this.values.get(path)?.v;
  }

  /** Whether ``path``'s last value has Good quality. */
  good(path) {
    return this.values.get(path)?.q === "Good";
  }

  listen(fn) {
    this.listeners.add(fn);
    return () => this.listeners.delete(fn);
  }

  clear() {
    this.values.clear();
  }
}

/** A number for display: ``digits`` significant digits, "—" when missing. */
export function fmt(value, digits = 4) {
  if (value === undefined || value === null) return "—";
  if (typeof value === "number") {
    if (!Number.isFinite(value)) return String(value);
    if (value !== 0 && (Math.abs(value) < 1e-3 || Math.abs(value) >= 1e5)) return value.toExponential(digits - 1);
    return Number(value.toPrecision(digits)).toString();
  }
  if (Array.isArray(value)) return `[${value.length}]`;
  return String(value);
}

/** Create an element: el("button", {type: "button", dataset: {action: "x"}}, "text", child...). */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs)) {
    if (value === undefined || value === null || value === false) continue;
    if (key === "dataset") Object.assign(node.dataset, value);
    else if (key === "text") node.textContent = value;
    else if (key.startsWith("on") && typeof value === "function") node.addEventListener(key.slice(2), value);
    else if (value === true) node.setAttribute(key, "");
    else node.setAttribute(key, String(value));
  }
  for (const child of children) {
    if (child === null || child === undefined || child === false) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}
