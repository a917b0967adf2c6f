// Scheduling into a contact window from the timeline (docs/console.md, "Timeline and
// countdown"): an operator picks a listed window, a stored plan and a name, and the console
// asks POST /api/passes naming the window (mission, relay, AOS: PassCreateFromWindow). The
// ground computes the window again, fits the plan and the start lead to its net time and
// stores the window with the pass; its refusal (409 plan_exceeds_window, 404
// no_such_window, ...) is shown with its message and code.

import {
  ApiError, getAll, post,
  type PassPublic, type PlanBrief, type WindowPublic,
} from "../api";
import { clear, fmt, h } from "../ui";
import { utcText } from "../windows";

const hm = (ms: number): string => new Date(ms).toISOString().slice(11, 16);

/** The form that schedules a pass into one window at a time, in ``panel``. */
export class WindowScheduler {
  private plans: PlanBrief[] | null = null;
  private loading: Promise<PlanBrief[]> | null = null;

  constructor(
    private readonly panel: HTMLElement,
    private readonly onScheduled: (pass: PassPublic) => void,
  ) {
    panel.hidden = true;
  }

  private storedPlans(): Promise<PlanBrief[]> {
    if (this.plans !== null) return Promise.resolve(this.plans);
    this.loading ??= getAll<PlanBrief>("/api/plans", 200).then((plans) => (this.plans = plans));
    return this.loading;
  }

  close(): void {
    clear(this.panel);
    this.panel.hidden = true;
  }

  /** The form for ``window`` of ``mission`` (replacing any other). */
  open(mission: string, window: WindowPublic, index: number): void {
    clear(this.panel);
    this.panel.hidden = false;
    this.panel.dataset.index = String(index);
    const aos = Date.parse(window.aos_time);
    const title = `Schedule a pass in ${window.relay}'s window: AOS ${utcText(aos)}, LOS ${utcText(Date.parse(window.los_time))}; `
      + `net time ${hm(Date.parse(window.net_start_time))}–${hm(Date.parse(window.net_end_time))}Z (${fmt(window.net_s / 60, 1)} min)`;
    const planSel = h("select", { name: "plan", "data-test": "tl-plan" }, h("option", { value: "" }, "Loading the stored plans…"));
    const name = h("input", {
      type: "text", name: "name", size: 40, "data-test": "tl-pass-name",
      value: `${mission} ${window.relay} ${new Date(aos).toISOString().slice(0, 16).replace("T", " ")}Z`,
    });
    const submit = h("button.primary", { type: "submit", "data-test": "tl-schedule-submit", disabled: true }, "Schedule pass");
    const cancel = h("button", { type: "button", "data-test": "tl-schedule-cancel" }, "Cancel");
    const out = h("p", { role: "status", "data-test": "tl-schedule-result" });
    const form = h("form.schedule", { "data-test": "tl-schedule-form" },
      h("h3", { "data-test": "tl-schedule-title" }, title),
      h("label", {}, "Stored plan", planSel), h("label", {}, "Pass name", name), submit, cancel, out);
    this.panel.append(form);
    cancel.addEventListener("click", () => this.close());

    this.storedPlans()
      .then((plans) => {
        clear(planSel);
        if (!plans.length) {
          planSel.append(h("option", { value: "" }, "No stored plans: make one on the Planning page"));
          return;
        }
        for (const p of plans) {
          // the net time must hold the plan and the ground's start lead: the ground says if not
          const over = p.duration_s > window.net_s ? " · longer than the net time" : "";
          planSel.append(h("option", { value: p.id },
            `${p.experiment} · ${fmt(p.duration_s, 1)} s · ${p.n_commands} commands · ${p.id.slice(0, 8)}${over}`));
        }
        submit.disabled = false;
      })
      .catch((e: Error) => {
        out.className = "error";
        out.textContent = `The stored plans did not load: ${e.message}`;
      });

    form.addEventListener("submit", (ev) => {
      ev.preventDefault();
      if (!planSel.value) return;
      submit.disabled = true;
      out.className = "";
      out.textContent = "Scheduling…";
      post<PassPublic>("/api/passes", {
        plan_id: planSel.value,
        name: name.value.trim(),
        window: { mission, relay: window.relay, aos_time: window.aos_time },
      })
        .then((p) => {
          clear(out);
          out.className = "ok";
          out.dataset.pass = p.id;
          out.append(`Scheduled ${p.name} in ${window.relay}'s window, `
            + `${utcText(Date.parse(p.aos_time))} to ${utcText(Date.parse(p.los_time))} (its net time). `,
          h("a", { href: `#/live/${p.id}`, "data-test": "tl-open-live" }, "Open the live view"));
          this.onScheduled(p);
        })
        .catch((e: Error) => {
          out.className = "error";
          out.dataset.code = e instanceof ApiError ? e.code : "error";
          out.textContent = e instanceof ApiError ? `${e.message} (${e.code})` : e.message;
        })
        .finally(() => (submit.disabled = false));
    });
  }
}
