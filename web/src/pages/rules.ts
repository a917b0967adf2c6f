// The flight rules of a plan, as the planner checked its predicted motion: one row per rule
// (worst value, limit, verdict, when, and for clearance the two bodies), failing rows
// marked, and the least clearance over all pairs of bodies against time with the limit
// drawn. Shown by the plan preview, the live pass view and the report (PassView).

import { clearanceRow, type FlightRulesReport, type RuleRow } from "../flightrules";
import { COLORS, timePlot, type TimePlot } from "../plots";
import { request } from "../api";
import { clear, fmt, h } from "../ui";

const RULE_TITLES: Record<string, string> = {
  clearance: "Clearance to the spacecraft",
  self_clearance: "Clearance between arm links",
  attitude_excursion_feedback: "Attitude excursion (feedback)",
  attitude_excursion_free_drift: "Attitude excursion (free drift)",
  wheel_momentum: "Wheel momentum",
  joint_limit_margin: "Joint-limit margin",
  hand_speed: "Hand speed",
  fits_pass: "Fits its pass",
};

const LIMIT_COLOR = "#ef5350";

/** A rule's value in its unit, with the digits that matter for it. */
export function ruleValue(value: number, unit: string): string {
  switch (unit) {
    case "m":
      return `${fmt(value, 3)} m`;
    case "m/s":
      return `${fmt(value, 3)} m/s`;
    case "deg":
      return `${fmt(value, 2)} deg`;
    case "of limit":
      return `${fmt(100 * value, 1)} % of limit`;
    case "s":
      return `${fmt(value, 1)} s`;
    default:
      return `${fmt(value, 3)} ${unit}`;
  }
}

function ruleRow(row: RuleRow): HTMLElement {
  const failed = row.verdict === "fail";
  const bodies = row.bodies ? `${row.bodies[0]} – ${row.bodies[1]}` : "";
  return h(`tr${failed ? ".fail" : ""}`, { "data-rule": row.rule, "data-verdict": row.verdict },
    h("td", { title: row.rule }, RULE_TITLES[row.rule] ?? row.rule),
    h("td.num", { "data-test": "rule-value" }, ruleValue(row.value, row.unit)),
    h("td.num", {}, `${row.bound === "min" ? "≥" : "≤"} ${ruleValue(row.limit, row.unit)}`),
    h(`td.verdict.${failed ? "bad" : "ok"}`, {}, failed ? "FAIL" : "pass"),
    h("td.num", {}, row.t_s === null ? "—" : `${fmt(row.t_s, 2)} s`),
    h("td", { "data-test": "rule-bodies" }, bodies),
    h("td.muted.small", {}, row.detail));
}

/** The report's table (a row per rule, the failing ones marked). */
export function rulesTable(report: FlightRulesReport): HTMLElement {
  return h("table.list.rules", { "data-test": "rules-table" },
    h("tr", {}, ...["rule", "worst", "limit", "verdict", "at", "bodies", ""].map((c) => h("th", {}, c))),
    ...report.rows.map(ruleRow));
}

/** The report's headline: passed or the rules it fails, and how it was checked. */
export function rulesSummary(report: FlightRulesReport): HTMLElement {
  const failing = report.rows.filter((r) => r.verdict === "fail");
  const verdict = report.passed
    ? h("span.badge.pass", { "data-test": "rules-verdict" }, "FLIGHT RULES PASS")
    : h("span.badge.fail", { "data-test": "rules-verdict" },
      `FLIGHT RULES FAIL: ${failing.map((r) => RULE_TITLES[r.rule] ?? r.rule).join(", ")}`);
  return h("p.rules-summary", {}, verdict, " ",
    h("span.muted.small", {},
      `robot ${report.robot} · ${report.n_pairs} pairs of bodies · ${report.n_samples} samples ` +
      `at ${fmt(report.step_s, 4)} s · ${report.n_queries} distance queries`));
}

/** The flight rules panel: summary, table, the clearance plot, and a button that shows the
 * worst moment in 3D (``onShowWorst``, given the worst pair's time). */
export class RulesPanel {
  readonly el: HTMLElement;
  /** The least clearance against plan time, with the limit as a second (dashed) line. */
  readonly plot: TimePlot;
  private readonly body: HTMLElement;
  private readonly worstButton: HTMLButtonElement;
  private worstT: number | null = null;
  /** A plan without a report can be checked from here (``offerCheck``). */
  private checkOffer: { planId: string; done: (report: FlightRulesReport) => void } | null = null;

  constructor(parent: HTMLElement, onShowWorst: (t: number) => void) {
    this.body = h("div.rules-body");
    this.worstButton = h("button", { type: "button", "data-test": "show-worst", hidden: true },
      "Show the worst moment in 3D");
    this.worstButton.addEventListener("click", () => {
      if (this.worstT !== null) onShowWorst(this.worstT);
    });
    const plotHolder = h("div.rules-plot");
    this.el = h("section.panel.rules", { "data-test": "flight-rules" },
      h("h3", {}, "Flight rules (the plan's predicted motion)"), this.body, plotHolder);
    parent.appendChild(this.el);
    this.plot = timePlot(plotHolder, "Least clearance over all pairs of bodies", "m", [
      { label: "least clearance", color: COLORS[0] },
      { label: "limit", color: LIMIT_COLOR, dash: [6, 4], width: 1.5 },
    ], 170, 0.05);
    this.plot.el.dataset.test = "plot-clearance";
    this.set(null);
  }

  /** With no report shown, offer to check plan ``planId`` now (``POST /api/plans/{id}/check``,
   * operator): the ground stores its report and ``done`` is given it. */
  offerCheck(planId: string, done: (report: FlightRulesReport) => void): void {
    this.checkOffer = { planId, done };
  }

  private checkButton(): HTMLElement {
    const offer = this.checkOffer;
    const message = h("span.field-error", { "data-test": "rules-check-error", role: "alert" });
    const button = h("button", { type: "button", "data-test": "rules-check" },
      "Check the flight rules now");
    button.addEventListener("click", () => {
      if (!offer) return;
      button.disabled = true;
      message.textContent = "";
      request<{ flight_rules: FlightRulesReport | null }>("POST", `/api/plans/${offer.planId}/check`)
        .then((plan) => {
          if (plan.flight_rules) {
            this.set(plan.flight_rules);
            offer.done(plan.flight_rules);
          }
        })
        .catch((err: Error) => {
          message.textContent = err.message;
          button.disabled = false;
        });
    });
    return h("div.rules-check", {}, button, message);
  }

  /** Show ``report`` (null: the plan was never checked, which is said plainly). */
  set(report: FlightRulesReport | null): void {
    clear(this.body);
    this.el.classList.toggle("failing", report !== null && !report.passed);
    const row = clearanceRow(report);
    this.worstT = row?.bodies && row.t_s !== null ? row.t_s : null;
    this.worstButton.hidden = this.worstT === null;
    if (report === null) {
      this.body.append(h("p.note", { "data-test": "rules-none" },
        "Not checked: this plan carries no flight-rules report (planned before the flight rules " +
        "or imported), so nothing shows it clear of the spacecraft, and no pass of it may " +
        "start until the ground has checked it."));
      if (this.checkOffer) this.body.append(this.checkButton());
      this.plot.el.hidden = true;
      this.plot.update([], [[], []]);
      return;
    }
    this.body.append(rulesSummary(report), rulesTable(report), this.worstButton);
    const trace = report.clearance;
    this.plot.el.hidden = trace.t_s.length === 0;
    this.plot.el.dataset.limit = row ? String(row.limit) : "";
    const limit = row ? trace.t_s.map(() => row.limit) : trace.t_s.map(() => null);
    this.plot.update(trace.t_s, [trace.min_m, limit]);
  }

  setMarker(t: number | null): void {
    this.plot.setMarker(t);
  }

  setXRange(range: [number, number] | null): void {
    this.plot.setXRange(range);
  }

  dispose(): void {
    this.plot.plot.destroy();
  }
}
