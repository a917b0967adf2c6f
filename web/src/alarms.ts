// Alarms on the console (docs/alarms.md): the five severities with their colours, the
// alarms known to this tab (a REST load, then the `alarms` topic's messages merged in by
// their `updated_time_ns`), and how an alarm's values read (units, limits, times).

import { get } from "./api";
import { SEVERITIES } from "./protocol.gen";
import type { AlarmPublic, LinkStatus, Severity } from "./protocol.gen";
import { fmt } from "./ui";

export type Alarm = AlarmPublic;
export type { Severity };

/** Yamcs's five levels, worst first (the order the banner and the list show them in). */
export const SEVERITIES_WORST_FIRST: readonly Severity[] = [...SEVERITIES].reverse();

/** Watch 1 .. severe 5. */
export const SEVERITY_RANK = Object.fromEntries(
  SEVERITIES.map((s, k) => [s, k + 1]),
) as Record<Severity, number>;

/** One colour a severity each, read at a glance: blue watch, yellow warning (COSMOS's
 * yellow), orange distress, red critical (COSMOS's red), magenta severe. */
export const SEVERITY_COLORS: Record<Severity, string> = {
  watch: "#4fc3f7",
  warning: "#fdd835",
  distress: "#fb8c00",
  critical: "#e53935",
  severe: "#d81b60",
};

/** Listed: still in a band, or not yet acknowledged (latching). */
export function isActive(a: Alarm): boolean {
  return a.state === "triggered" || !a.acknowledged;
}

/** Whether ``a`` is at least as recent as ``b`` (the same alarm): by ``updated_time_ns``,
 * an acknowledgement winning a tie (it is never undone). */
function newer(a: Alarm, b: Alarm): boolean {
  if (a.updated_time_ns !== b.updated_time_ns) return a.updated_time_ns > b.updated_time_ns;
  return a.acknowledged || !b.acknowledged;
}

/** A value in an alarm's unit (a fraction as a percentage). */
export function alarmValue(value: number | null | undefined, unit: string): string {
  if (value === null || value === undefined || !Number.isFinite(value)) return "—";
  if (unit === "1") return `${fmt(100 * value, 1)} %`;
  const size = Math.abs(value);
  const digits = size >= 100 ? 0 : size >= 10 ? 1 : size >= 0.1 || size === 0 ? 2 : 3;
  return `${fmt(value, digits)} ${unit}`;
}

/** The limit crossed: ``≥ 5.00 deg`` for a "high" quantity, ``≤ 0.030 m`` for a "low" one. */
export function alarmLimit(a: Alarm): string {
  if (a.limit === null) return "—";
  return `${a.direction === "high" ? "≥" : "≤"} ${alarmValue(a.limit, a.unit)}`;
}

/** What the alarm is about, for a label: ``Joint tracking error joint3``. */
export function alarmSubject(a: Alarm): string {
  return a.channel ? `${a.label} ${a.channel}` : a.label;
}

/** A ground or onboard time (ns since the Unix epoch) as ``HH:MM:SS.s`` UTC. */
export function timeOfDay(ns: number | null | undefined): string {
  if (ns === null || ns === undefined) return "—";
  const text = new Date(ns / 1e6).toISOString();
  return `${text.slice(11, 21)}Z`;
}

export interface AlarmQuery {
  /** Only this pass's alarms (null: every pass's, and the vehicle's without a pass). */
  passId: string | null;
  /** true: only the listed ones; false: all of them (the REST's ``active`` left out). */
  activeOnly: boolean;
}

/**
 * The alarms matching a query, kept current: :meth:`load` reads them from REST (again after
 * a resync), :meth:`apply` takes each ``alarm`` message of the topic. An alarm no longer
 * active leaves an active-only book. Listeners hear every change.
 */
export class AlarmBook {
  private readonly byId = new Map<string, Alarm>();
  private readonly listeners = new Set<() => void>();
  /** How many times the REST load answered (0: not yet). */
  loaded = 0;
  error: string | null = null;
  private loading: Promise<void> | null = null;

  constructor(readonly query: AlarmQuery) {}

  private matches(a: Alarm): boolean {
    if (this.query.passId !== null && a.pass_id !== this.query.passId) return false;
    return !this.query.activeOnly || isActive(a);
  }

  /** Read them from REST (every page), merged with what the topic brought meanwhile. */
  load(): Promise<void> {
    if (this.loading) return this.loading;
    this.loading = this.fetchAll()
      .then((alarms) => {
        const seen = new Set<string>();
        for (const a of alarms) {
          seen.add(a.id);
          const known = this.byId.get(a.id);
          if (!known || newer(a, known)) this.byId.set(a.id, a);
        }
        // Gone from the answer: no longer matching (acknowledged and cleared elsewhere
        // while the topic was not heard), unless a message newer than the answer says otherwise.
        for (const [id, a] of this.byId) if (!seen.has(id) && !this.matches(a)) this.byId.delete(id);
        this.loaded++;
        this.error = null;
      })
      .catch((e: Error) => {
        this.error = e.message;
      })
      .finally(() => {
        this.loading = null;
        this.emit();
      });
    return this.loading;
  }

  private async fetchAll(): Promise<Alarm[]> {
    const params = new URLSearchParams();
    if (this.query.passId !== null) params.set("pass", this.query.passId);
    if (this.query.activeOnly) params.set("active", "true");
    const out: Alarm[] = [];
    for (;;) {
      params.set("offset", String(out.length));
      params.set("limit", "1000");
      const page = await get<{ alarms: Alarm[]; count: number }>(`/api/alarms?${params}`);
      out.push(...page.alarms);
      if (page.alarms.length === 0 || out.length >= page.count) return out;
    }
  }

  /** An alarm as the topic (or an acknowledgement's answer) gives it. */
  apply(a: Alarm): void {
    const known = this.byId.get(a.id);
    if (known && !newer(a, known)) return;
    if (this.matches(a)) this.byId.set(a.id, a);
    else if (known) this.byId.delete(a.id);
    else return;
    this.emit();
  }

  /** Newest raised first. */
  list(): Alarm[] {
    return [...this.byId.values()].sort((a, b) => b.raised_time_ns - a.raised_time_ns);
  }

  /** The active alarms counted by their worst severity. */
  counts(): Record<Severity, number> {
    const out: Record<Severity, number> = { watch: 0, warning: 0, distress: 0, critical: 0, severe: 0 };
    for (const a of this.byId.values()) if (isActive(a)) out[a.severity]++;
    return out;
  }

  onChange(fn: () => void): () => void {
    this.listeners.add(fn);
    return () => this.listeners.delete(fn);
  }

  private emit(): void {
    for (const fn of [...this.listeners]) fn();
  }
}

/** The vehicle's last on-board safing report as the link status gives it (``safing``: the
 * wire's ``Safing`` and the pass it stopped, docs/alarms.md); null before any. */
export interface SafingReport {
  state: "safe" | "nominal";
  since_time_ns: number | null;
  trigger: { quantity: string; channel: string; value: number; limit: number; detail?: string | null } | null;
  cancelled: number;
  exit_request_id: number | null;
  onboard_time_ns: number;
  pass_id?: string | null;
}

/** The link status with its ``safing`` report typed (generated as a plain object). */
export type LinkWithMode = Omit<LinkStatus, "safing"> & { safing: SafingReport | null };

/** The trigger of a safing report, in words: ``joint_tracking_error_deg joint3 = 6.25
 * (limit 5)``. */
export function triggerText(report: SafingReport | null | undefined): string {
  const t = report?.trigger;
  if (!t) return "trigger not reported";
  const what = t.channel ? `${t.quantity} ${t.channel}` : t.quantity;
  const digits = Math.abs(t.value) >= 10 ? 1 : 3;
  const text = `${what} = ${fmt(t.value, digits)} (limit ${fmt(t.limit, digits)})`;
  return t.detail ? `${text}: ${t.detail}` : text;
}

/** An alarm's time in a band, on a pass's plan clock (s from ``epochNs``, onboard): one
 * span per band it was in, from its timeline (the link's health, timed on the ground, has
 * none); the last open while the alarm is still triggered. */
export function alarmSpans(a: Alarm, epochNs: number): { t0: number; t1: number | null; severity: Severity }[] {
  const out: { t0: number; t1: number | null; severity: Severity }[] = [];
  let open: { t0: number; t1: number | null; severity: Severity } | null = null;
  for (const entry of a.timeline) {
    if (entry.generation_time_ns === null) continue;
    const t = (entry.generation_time_ns - epochNs) / 1e9;
    if (open) {
      open.t1 = t;
      out.push(open);
      open = null;
    }
    if (entry.severity !== null) open = { t0: t, t1: null, severity: entry.severity };
  }
  if (open) {
    // A timeline keeps its first and newest entries: a triggered alarm's band goes on.
    if (a.state === "cleared" && a.cleared_generation_time_ns !== null) open.t1 = (a.cleared_generation_time_ns - epochNs) / 1e9;
    out.push(open);
  }
  if (out.length === 0 && a.raised_generation_time_ns !== null) {
    const t1 = a.cleared_generation_time_ns === null ? null : (a.cleared_generation_time_ns - epochNs) / 1e9;
    out.push({ t0: (a.raised_generation_time_ns - epochNs) / 1e9, t1, severity: a.current_severity ?? a.severity });
  }
  return out;
}
