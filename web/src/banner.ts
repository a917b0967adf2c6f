// The alarm banner under the header of every page: the active alarms counted by severity
// (worst first, each severity its colour; a click opens the alarm list), and, while the
// vehicle is SAFE (the link status's vehicle_mode), a red strip saying so with its trigger
// and, for operators, the way out (Exit SAFE, behind the vehicle's name). Above them, an
// amber strip when the ground this console is on does not command the vehicle (a standby:
// the holder named) or cannot reach its database (the writes it journals meanwhile).

import {
  SEVERITIES_WORST_FIRST, SEVERITY_COLORS, isActive, timeOfDay, triggerText,
  type AlarmBook, type LinkWithMode,
} from "./alarms";
import type { Ctx } from "./main";
import { safeExitButton } from "./pages/control";
import { clear, h } from "./ui";

/** The link status's ``ground`` (server/services/ground_status.py). */
interface GroundStatus {
  command?: { role?: string; commanding?: boolean; lease_holder?: string | null; ground?: string };
  database?: { reachable?: boolean; down_s?: number | null; journal?: number };
}

/** What the ground strip says (none: this ground commands and its database answers). */
export function groundText(ground: GroundStatus | null | undefined): string | null {
  const parts: string[] = [];
  const command = ground?.command;
  if (command?.role === "standby") {
    parts.push(`STANDBY GROUND: ${command.lease_holder ?? "no ground"} commands the vehicle; starts and aborts go there`);
  } else if (command && command.commanding === false) {
    parts.push("COMMAND LEASE LAPSING: nothing is sent until the database answers (the vehicle flies what it holds)");
  }
  const db = ground?.database;
  if (db && db.reachable === false) {
    const since = db.down_s == null ? "" : ` for ${Math.round(db.down_s)} s`;
    parts.push(`DATABASE UNREACHABLE${since}: ${db.journal ?? 0} writes kept in order until it answers`);
  }
  return parts.length ? parts.join(" · ") : null;
}

export class AlarmBanner {
  readonly el: HTMLElement;
  private readonly ground: HTMLElement;
  private readonly safe: HTMLElement;
  private readonly summary: HTMLAnchorElement;
  private safeKey = "";

  constructor(
    private readonly ctx: Ctx,
    private readonly book: AlarmBook,
  ) {
    this.safe = h("div.safe-banner", { "data-test": "vehicle-safe", role: "alert", hidden: true });
    this.summary = h("a.alarm-summary", { href: "#/alarms", "data-test": "alarm-summary", title: "Open the alarm list" });
    this.ground = h("div.ground-banner", { "data-test": "ground-banner", role: "status", hidden: true });
    this.el = h("div.alarm-banner", { "data-test": "alarm-banner" }, this.ground, this.safe, this.summary);
    book.onChange(() => this.renderAlarms());
    this.renderAlarms();
  }

  renderAlarms(): void {
    const counts = this.book.counts();
    const listed = this.book.list().filter(isActive);
    const unacked = listed.filter((a) => !a.acknowledged).length;
    const total = listed.length;
    const worst = SEVERITIES_WORST_FIRST.find((s) => counts[s] > 0) ?? null;
    clear(this.summary);
    this.summary.dataset.total = String(total);
    this.summary.dataset.worst = worst ?? "";
    this.summary.dataset.loaded = String(this.book.loaded > 0);
    this.el.classList.toggle("has-alarms", total > 0);
    this.summary.style.setProperty("--worst", worst ? SEVERITY_COLORS[worst] : "transparent");
    this.summary.append(h("span.alarm-title", {}, total ? "ALARMS" : "Alarms"));
    for (const s of SEVERITIES_WORST_FIRST) {
      const n = counts[s];
      this.summary.append(h(`span.sev.sev-${s}${n ? "" : ".zero"}`,
        { "data-severity": s, "data-count": n, style: `--c:${SEVERITY_COLORS[s]}` },
        h("b", {}, String(n)), ` ${s.toUpperCase()}`));
    }
    let note: string;
    if (this.book.error !== null && this.book.loaded === 0) note = `alarms not available: ${this.book.error}`;
    else if (total === 0) note = "no active alarms";
    else note = unacked ? `${unacked} unacknowledged` : "all acknowledged";
    this.summary.append(h("span.alarm-note", { "data-test": "alarm-unacked", "data-count": unacked }, note));
  }

  /** The vehicle's mode from a link status (its ``vehicle_mode`` and last ``safing``). */
  setLink(status: LinkWithMode | null): void {
    const ground = groundText(status?.ground as GroundStatus | null | undefined);
    this.ground.hidden = ground === null;
    this.ground.textContent = ground ?? "";
    const safe = status?.vehicle_mode === "safe";
    const report = status?.safing ?? null;
    const vehicle = status?.vehicle ?? null;
    const key = safe ? JSON.stringify([vehicle, report?.since_time_ns, report?.trigger, report?.cancelled]) : "";
    if (key === this.safeKey) return;
    this.safeKey = key;
    this.safe.hidden = !safe;
    document.body.classList.toggle("vehicle-safe", safe);
    clear(this.safe);
    if (!safe) return;
    const text = h("div.safe-text", {},
      h("b.safe-title", {}, `VEHICLE SAFE${vehicle ? ` (${vehicle})` : ""}`),
      ` since ${timeOfDay(report?.since_time_ns)} onboard`,
      h("span.safe-trigger", { "data-test": "safe-trigger" }, ` · trigger: ${triggerText(report)}`),
      report?.cancelled ? ` · ${report.cancelled} commands dropped` : "",
      h("div.small", {}, "Holding: joints at their measured angles, attitude in feedback; commands refused until the ground sends the exit."));
    const parts: (Node | null)[] = [text, vehicle ? safeExitButton(this.ctx, vehicle) : null];
    for (const part of parts) if (part !== null) this.safe.append(part);
  }
}
