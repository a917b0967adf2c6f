// Small DOM helpers, formatting, and the confirmation dialog for critical actions.

type Attrs = Record<string, string | number | boolean | EventListener | undefined | null>;

/** ``h("button.primary", {onclick}, "Start")``: an element with classes, attributes, children. */
export function h<K extends keyof HTMLElementTagNameMap>(
  spec: K | `${K}.${string}` | `${K}#${string}`,
  attrs: Attrs = {},
  ...children: (Node | string | null | undefined | false)[]
): HTMLElementTagNameMap[K] {
  const [tagAndId, ...classes] = spec.split(".");
  const [tag, id] = tagAndId.split("#");
  const el = document.createElement(tag as K);
  if (id) el.id = id;
  if (classes.length) el.className = classes.join(" ");
  for (const [name, value] of Object.entries(attrs)) {
    if (value === undefined || value === null || value === false) continue;
    if (typeof value === "function") el.addEventListener(name.replace(/^on/, ""), value);
    else if (value === true) el.setAttribute(name, "");
    else el.setAttribute(name, String(value));
  }
  for (const child of children) {
    if (child === null || child === undefined || child === false) continue;
    el.append(child);
  }
  return el;
}

export function clear(el: HTMLElement): void {
  while (el.firstChild) el.removeChild(el.firstChild);
}

/** ``m:ss`` or ``h:mm:ss`` of a duration in seconds (sign kept). */
export function clock(seconds: number): string {
  const sign = seconds < 0 ? "-" : "";
  let s = Math.floor(Math.abs(seconds));
  const hours = Math.floor(s / 3600);
  s -= hours * 3600;
  const mm = String(Math.floor(s / 60)).padStart(hours ? 2 : 1, "0");
  const ss = String(s % 60).padStart(2, "0");
  return hours ? `${sign}${hours}:${mm}:${ss}` : `${sign}${mm}:${ss}`;
}

export function fmt(value: number | null | undefined, digits = 2): string {
  return value === null || value === undefined || !Number.isFinite(value) ? "—" : value.toFixed(digits);
}

/** An ISO-8601 UTC time as ``HH:MM:SS`` UTC (date added when not today). */
export function utc(iso: string): string {
  const d = new Date(iso);
  const text = d.toISOString();
  const today = new Date().toISOString().slice(0, 10);
  return (text.slice(0, 10) === today ? "" : text.slice(0, 10) + " ") + text.slice(11, 19) + "Z";
}

/**
 * The confirmation of a critical action: the operator types the pass name (or another
 * ``noun``'s: the vehicle's for leaving SAFE). Resolves with
 * the extra field's value (e.g. the abort reason) when confirmed, null when cancelled.
 */
export function confirmAction(opts: {
  action: string;
  /** The name to type: the pass's (or, with ``noun``, the vehicle's). */
  passName: string;
  /** What is named (``pass`` unless given). */
  noun?: string;
  danger?: boolean;
  reason?: { label: string; value: string };
  run: (reason: string) => Promise<void>;
}): void {
  const input = h("input", { type: "text", autocomplete: "off", spellcheck: "false", "data-test": "confirm-input" });
  const reason = opts.reason
    ? h("input", { type: "text", value: opts.reason.value, "data-test": "confirm-reason" })
    : null;
  const error = h("p.error", { role: "alert" });
  const go = h(
    `button.${opts.danger ? "danger" : "primary"}`,
    { type: "submit", disabled: true, "data-test": "confirm-go" },
    `${opts.action} ${opts.passName}`,
  );
  const cancel = h("button", { type: "button", "data-test": "confirm-cancel" }, "Cancel");
  const noun = opts.noun ?? "pass";
  const form = h(
    "form.dialog",
    {},
    h("h2", {}, `${opts.action} ${noun}`),
    h("p", {}, `Type the ${noun} name `, h("code", {}, opts.passName), " to confirm."),
    h("label", {}, `${noun[0].toUpperCase()}${noun.slice(1)} name`, input),
    reason ? h("label", {}, opts.reason!.label, reason) : null,
    error,
    h("div.actions", {}, cancel, go),
  );
  const backdrop = h("div.backdrop", { role: "dialog", "aria-modal": "true" }, form);
  const close = (): void => backdrop.remove();
  input.addEventListener("input", () => {
    go.disabled = input.value !== opts.passName;
  });
  cancel.addEventListener("click", close);
  backdrop.addEventListener("keydown", (ev) => {
    if ((ev as KeyboardEvent).key === "Escape") close();
  });
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    if (input.value !== opts.passName) return;
    go.disabled = true;
    error.textContent = "";
    opts
      .run(reason?.value.trim() || opts.reason?.value || "")
      .then(close)
      .catch((e: Error) => {
        error.textContent = refusal(e);
        go.disabled = false;
      });
  });
  document.body.appendChild(backdrop);
  input.focus();
}

/** A refused request in words: the server's message and its error code (``ApiError``'s). */
export function refusal(e: Error): string {
  const code = (e as Error & { code?: unknown }).code;
  return typeof code === "string" && code && !e.message.includes(code) ? `${e.message} (${code})` : e.message;
}
