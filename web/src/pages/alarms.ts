// The alarm list (#/alarms[/active|all[/PASS]]): every alarm with its severity, what it
// watches, its values against its limit, when it was raised, how many frames were in a
// band, its state and its acknowledgement; live from the `alarms` topic. Operators
// acknowledge an alarm (with an optional comment); a viewer sees the action disabled, and why.

import {
  AlarmBook, SEVERITY_COLORS, alarmLimit, alarmSubject, alarmValue, isActive, timeOfDay,
  type Alarm,
} from "../alarms";
import { getAll, post, type PassPublic } from "../api";
import type { Ctx } from "../main";
import { clear, h, refusal } from "../ui";

/** Why a viewer's Acknowledge is disabled. */
export const VIEWER_CANNOT_ACK = "Acknowledging an alarm needs the operator role (signed in as viewer).";

export function alarmsPage(root: HTMLElement, ctx: Ctx, params: string[]): () => void {
  const activeOnly = params[0] !== "all";
  const passId = params[1] ?? null;
  // The active alarms of every pass are the shell's already; any other view has its own book.
  const book = activeOnly && passId === null ? ctx.alarms : new AlarmBook({ passId, activeOnly });
  const own = book !== ctx.alarms;
  const passes = new Map<string, PassPublic>();

  const which = h("select", { "data-test": "alarms-which" },
    h("option", { value: "active", selected: activeOnly }, "active (triggered or not acknowledged)"),
    h("option", { value: "all", selected: !activeOnly }, "all"));
  const passSel = h("select", { "data-test": "alarms-pass" }, h("option", { value: "" }, "every pass"));
  const go = (): void => {
    const pass = passSel.value;
    location.hash = `#/alarms/${which.value}${pass ? `/${encodeURIComponent(pass)}` : ""}`;
  };
  which.addEventListener("change", go);
  passSel.addEventListener("change", go);
  const note = h("p.muted.small", { "data-test": "alarms-note" });
  const table = h("table.list.alarms", { "data-test": "alarms" });
  root.append(
    h("section.passbar", {}, h("h1", {}, "Alarms"),
      h("label.inline", {}, "Show ", which), h("label.inline", {}, "Pass ", passSel)));
  if (!ctx.canCommand) root.append(h("p.note.small", { "data-test": "viewer-note" }, VIEWER_CANNOT_ACK));
  root.append(note, table);

  const passName = (id: string | null): Node | string => {
    if (id === null) return h("span.muted", {}, "no pass");
    const p = passes.get(id);
    return h("a", { href: `#/live/${id}` }, p ? p.name : id.slice(0, 8));
  };

  const ackCell = (a: Alarm): HTMLElement => {
    if (a.acknowledged) {
      return h("td.ack", { "data-test": "ack" },
        h("span", {}, `${a.acknowledged_by ?? "?"} at ${timeOfDay(a.acknowledged_time_ns)}`),
        a.comment ? h("div.small", { "data-test": "ack-comment" }, `“${a.comment}”`) : null);
    }
    const button = h("button.primary", {
      type: "button", "data-test": "acknowledge", disabled: !ctx.canCommand,
      title: ctx.canCommand ? "Acknowledge this alarm (optionally with a comment)" : VIEWER_CANNOT_ACK,
    }, "Acknowledge…");
    if (ctx.canCommand) button.addEventListener("click", () => acknowledgeDialog(a, book, ctx));
    return h("td.ack", { "data-test": "ack" }, button);
  };

  const row = (a: Alarm): HTMLElement => {
    const now = a.current_severity;
    return h(`tr.alarm.${isActive(a) ? "active" : "inactive"}`, {
      "data-alarm": a.id, "data-quantity": a.quantity, "data-channel": a.channel, "data-severity": a.severity,
      "data-state": a.state, "data-acknowledged": a.acknowledged, "data-pass": a.pass_id ?? "",
      style: `--c:${SEVERITY_COLORS[a.severity]}`,
    },
      h("td", {}, h(`span.sev.sev-${a.severity}`, { "data-test": "severity", style: `--c:${SEVERITY_COLORS[a.severity]}` }, a.severity.toUpperCase()),
        now !== null && now !== a.severity ? h("div.small.muted", {}, `now ${now}`) : null),
      h("td", { title: a.quantity }, a.source === "vehicle" ? h("b", {}, "Vehicle safed: ") : null, a.label,
        a.detail ? h("div.small.muted", { "data-test": "alarm-detail" }, a.detail) : null),
      h("td.mono", { "data-test": "channel" }, a.channel || "—"),
      h("td.num", { "data-test": "worst" }, alarmValue(a.worst_value, a.unit)),
      h("td.num", { "data-test": "last" }, alarmValue(a.last_value, a.unit)),
      h("td.num", { "data-test": "limit" }, alarmLimit(a)),
      h("td.mono", { title: `frame ${a.raised_frame_seq ?? "—"}, onboard ${timeOfDay(a.raised_generation_time_ns)}` }, timeOfDay(a.raised_time_ns)),
      h("td.num", { "data-test": "count" }, String(a.count)),
      h("td", { "data-test": "state" }, h(`span.alarm-state.${a.state}`, {}, a.state === "triggered" ? "TRIGGERED" : "cleared"),
        a.state === "cleared" && a.cleared_time_ns !== null ? h("div.small.muted", {}, timeOfDay(a.cleared_time_ns)) : null),
      h("td", {}, passName(a.pass_id)),
      ackCell(a));
  };

  const render = (): void => {
    const alarms = book.list();
    clear(table);
    table.dataset.count = String(alarms.length);
    table.append(h("tr", {}, ...["Severity", "Quantity", "Channel", "Worst", "Last", "Limit", "Raised (ground)", "Frames",
      "State", "Pass", "Acknowledged"].map((t) => h("th", {}, t))));
    for (const a of alarms) table.append(row(a));
    if (book.error !== null) {
      note.textContent = `Alarms not available: ${book.error}`;
      note.className = "error";
    } else {
      note.className = "muted small";
      note.textContent = book.loaded === 0 ? "Loading…"
        : alarms.length === 0 ? (activeOnly ? "No active alarms." : "No alarms.")
          : `${alarms.length} alarm${alarms.length === 1 ? "" : "s"}, newest raised first; live.`;
    }
  };

  const offBook = book.onChange(render);
  const offMessage = own ? ctx.on((m) => {
    if (m.type === "alarm") book.apply(m.alarm);
  }) : () => undefined;
  const offResync = own ? ctx.onResync((topic) => {
    if (topic === "alarms") void book.load();
  }) : () => undefined;
  if (own) void book.load();
  render();

  getAll<PassPublic>("/api/passes").then((list) => {
    for (const p of list) passes.set(p.id, p);
    for (const p of [...list].reverse()) passSel.append(h("option", { value: p.id, selected: p.id === passId }, `${p.name} (${p.state})`));
    render();
  }).catch(() => undefined);

  return () => {
    offBook();
    offMessage();
    offResync();
  };
}

/** The acknowledgement, with an optional comment; the server's answer updates the list at
 * once (the topic brings it too). A refusal (already acknowledged by someone else) shows. */
function acknowledgeDialog(a: Alarm, book: AlarmBook, ctx: Ctx): void {
  const comment = h("textarea", { "data-test": "ack-comment-input", maxlength: 500, rows: 3, placeholder: "optional" });
  const error = h("p.error", { role: "alert", "data-test": "ack-error" });
  const go = h("button.primary", { type: "submit", "data-test": "ack-go" }, "Acknowledge");
  const cancel = h("button", { type: "button", "data-test": "ack-cancel" }, "Cancel");
  const form = h("form.dialog", {},
    h("h2", {}, "Acknowledge alarm"),
    h("p", {}, h(`span.sev.sev-${a.severity}`, { style: `--c:${SEVERITY_COLORS[a.severity]}` }, a.severity.toUpperCase()),
      ` ${alarmSubject(a)}: worst ${alarmValue(a.worst_value, a.unit)} (${alarmLimit(a)}), ${a.state}.`),
    h("label", {}, "Comment (audit log)", comment),
    error,
    h("div.actions", {}, cancel, go));
  const backdrop = h("div.backdrop", { role: "dialog", "aria-modal": "true" }, form);
  const close = (): void => backdrop.remove();
  cancel.addEventListener("click", close);
  backdrop.addEventListener("keydown", (ev) => {
    if ((ev as KeyboardEvent).key === "Escape") close();
  });
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    go.disabled = true;
    error.textContent = "";
    const text = comment.value.trim();
    post<Alarm>(`/api/alarms/${a.id}/acknowledge`, { comment: text || null })
      .then((alarm) => {
        book.apply(alarm);
        if (book !== ctx.alarms) ctx.alarms.apply(alarm);
        close();
      })
      .catch((e: Error) => {
        error.textContent = refusal(e);
        go.disabled = false;
      });
  });
  document.body.appendChild(backdrop);
  comment.focus();
}
