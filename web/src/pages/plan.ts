// Planning: choose an experiment, edit its parameters, validate (errors inline, at the
// field they name), plan it, preview the predicted trajectories and the 3D motion before
// anything is uplinked, and schedule a pass of it. Operators plan and schedule; viewers
// can preview stored plans.

import {
  ApiError, get, getAll, post,
  type PassPublic, type PlanBrief, type PlanDocument, type PlanPublic, type PlanValidation,
} from "../api";
import type { Ctx } from "../main";
import { clear, fmt, h } from "../ui";
import { EXPERIMENTS, type ParamSpec } from "./experiments";
import { PassView, predictionColumns } from "./passview";

const norm = (s: string): string => s.replace(/\s+/g, "").toLowerCase();

export function planPage(root: HTMLElement, ctx: Ctx, params: string[]): () => void {
  const cleanups: (() => void)[] = [];
  if (params[0]) {
    cleanups.push(previewPlan(root, ctx, params[0]));
  } else {
    if (ctx.canCommand) planForm(root);
    else root.append(h("p.note", { "data-test": "viewer-note" }, "Planning and scheduling need the operator role; you can preview the stored plans."));
    storedPlans(root);
  }
  return () => cleanups.forEach((f) => f());
}

function planForm(root: HTMLElement): void {
  const select = h("select", { "data-test": "experiment" },
    ...Object.entries(EXPERIMENTS).map(([name, e]) => h("option", { value: name }, `${name}: ${e.title}`)));
  const fields = h("div.fields");
  const result = h("div.result", { "data-test": "validation" });
  const validate = h("button", { type: "button", "data-test": "validate" }, "Validate");
  const create = h("button.primary", { type: "submit", "data-test": "create-plan" }, "Plan it");
  const form = h("form.planform", {},
    h("h1", {}, "Plan an experiment"),
    h("label", {}, "Experiment", select),
    fields,
    h("div.actions", {}, validate, create),
    result);
  root.append(form);
  let inputs = new Map<string, { spec: ParamSpec; input: HTMLInputElement | HTMLSelectElement; error: HTMLElement }>();

  const build = (): void => {
    clear(fields);
    clear(result);
    inputs = new Map();
    for (const spec of EXPERIMENTS[select.value].params) {
      const input =
        spec.type === "bool"
          ? h("select", { name: spec.name }, h("option", { value: "true" }, "true"), h("option", { value: "false" }, "false"))
          : h("input", { type: "text", name: spec.name, value: spec.default, spellcheck: "false", placeholder: spec.optional ? "default (derived)" : "" });
      if (spec.type === "bool") input.value = spec.default;
      const error = h("span.field-error", { "data-test": `error-${spec.name}`, role: "alert" });
      const unit = spec.type === "floats" || spec.type === "strings" ? " (comma-separated)" : "";
      fields.append(h("label.field", { "data-field": spec.name }, h("span.name", {}, spec.name, h("span.muted.small", {}, unit)), input, error));
      inputs.set(spec.name, { spec, input, error });
      input.addEventListener("input", () => {
        error.textContent = "";
        input.classList.remove("invalid");
      });
    }
  };

  const body = (): { experiment: string; parameters: Record<string, string> } => {
    const parameters: Record<string, string> = {};
    for (const [name, { spec, input }] of inputs) {
      const text = input.value.trim();
      if (text === "" || norm(text) === norm(spec.default)) continue;
      parameters[name] = text;
    }
    return { experiment: select.value, parameters };
  };

  const showErrors = (errors: { code: string; message: string }[]): void => {
    clear(result);
    for (const { input, error } of inputs.values()) {
      error.textContent = "";
      input.classList.remove("invalid");
    }
    const unplaced: string[] = [];
    for (const e of errors) {
      // Planner messages name the parameter ("parameter settle_s = ..."): show it there.
      const name = [...inputs.keys()].sort((a, b) => b.length - a.length).find((n) => e.message.includes(n));
      const target = name ? inputs.get(name) : undefined;
      if (target) {
        target.error.textContent = e.message;
        target.input.classList.add("invalid");
      } else unplaced.push(`${e.code}: ${e.message}`);
    }
    result.append(h("p.error", { "data-test": "validation-errors" }, `Not valid (${errors.length} error${errors.length === 1 ? "" : "s"})`),
      ...unplaced.map((m) => h("p.error", {}, m)));
  };

  const showSummary = (v: PlanValidation): void => {
    clear(result);
    const s = v.summary!;
    result.append(
      h("p.ok", { "data-test": "validation-ok" }, `Valid: ${fmt(s.duration_s, 1)} s, ${s.n_commands} commands, ${s.segments.length} segments`),
      h("table.list", {}, ...Object.entries(s.metrics).map(([k, val]) => h("tr", {}, h("th", {}, k), h("td", {}, fmt(val, 6))))));
  };

  const busy = (on: boolean, what: string): void => {
    validate.disabled = on;
    create.disabled = on;
    if (on) {
      clear(result);
      result.append(h("p.muted", {}, what));
    }
  };

  validate.addEventListener("click", () => {
    busy(true, "Validating (planning without storing)…");
    post<PlanValidation>("/api/plans/validate", body())
      .then((v) => (v.valid ? showSummary(v) : showErrors(v.errors)))
      .catch((e: Error) => showErrors([{ code: (e as ApiError).code ?? "error", message: e.message }]))
      .finally(() => busy(false, ""));
  });
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    busy(true, "Planning…");
    // Validate first: a refused plan is shown inline rather than as a failed request.
    post<PlanValidation>("/api/plans/validate", body())
      .then(async (v) => {
        if (!v.valid) return showErrors(v.errors);
        const plan = await post<PlanPublic>("/api/plans", body());
        location.hash = `#/plan/${plan.id}`;
      })
      .catch((e: Error) => showErrors([{ code: (e as ApiError).code ?? "error", message: e.message }]))
      .finally(() => busy(false, ""));
  });
  select.addEventListener("change", build);
  build();
}

function storedPlans(root: HTMLElement): void {
  const table = h("table.list", { "data-test": "plans" });
  root.append(h("h2", {}, "Stored plans"), table);
  getAll<PlanBrief>("/api/plans", 200)
    .then((plans) => {
      if (!plans.length) table.append(h("tr", {}, h("td.muted", {}, "No plans yet.")));
      for (const p of plans.slice(0, 200)) {
        table.append(h("tr", {},
          h("td", {}, h("a", { href: `#/plan/${p.id}` }, p.experiment)),
          h("td", {}, `${fmt(p.duration_s, 1)} s`),
          h("td", {}, `${p.n_commands} commands`),
          h("td.muted", {}, JSON.stringify(p.parameters)),
          h("td.muted", {}, p.created_at.slice(0, 19).replace("T", " "))));
      }
    })
    .catch((e: Error) => table.append(h("tr", {}, h("td.error", {}, e.message))));
}

function previewPlan(root: HTMLElement, ctx: Ctx, planId: string): () => void {
  const head = h("div.passbar", {}, h("a", { href: "#/plan" }, "← Planning"), h("h1", {}, "Plan preview"));
  const info = h("div.panel", { "data-test": "plan-info" }, h("p.muted", {}, "Loading the plan…"));
  const schedule = h("div.panel", { "data-test": "schedule" });
  const scrub = h("input", { type: "range", min: "0", max: "1000", value: "0", step: "any", "data-test": "preview-scrub" });
  const play = h("button", { type: "button", "data-test": "preview-play" }, "▶ Play motion");
  const tLabel = h("span.mono");
  root.append(head, h("section.status", {}, info, schedule), h("div.replaybar", {}, play, scrub, tLabel));
  const view = new PassView(root, ctx.paths);
  let timer = 0;
  let duration = 0;
  const show = (t: number): void => {
    view.showPredictedAt(t);
    view.setMarker(t);
    tLabel.textContent = `t = ${fmt(t, 1)} s / ${fmt(duration, 1)} s`;
  };
  scrub.addEventListener("input", () => show((Number(scrub.value) / 1000) * duration));
  play.addEventListener("click", () => {
    if (timer) {
      window.clearInterval(timer);
      timer = 0;
      play.textContent = "▶ Play motion";
      return;
    }
    play.textContent = "❚❚ Pause";
    // The whole plan in about 20 s of wall time, at 20 frames/s.
    timer = window.setInterval(() => {
      const next = Math.min(1000, Number(scrub.value) + 1000 / 400);
      scrub.value = String(next >= 1000 ? 0 : next);
      show((Number(scrub.value) / 1000) * duration);
    }, 50);
  });

  Promise.all([get<PlanPublic>(`/api/plans/${planId}`), get<PlanDocument>(`/api/plans/${planId}/document`)])
    .then(([plan, doc]) => {
      const pred = predictionColumns(doc);
      duration = pred.t[pred.t.length - 1] ?? plan.duration_s;
      view.setPrediction(pred);
      view.showPredictionAsData(pred);
      show(0);
      clear(info);
      info.append(
        h("h3", {}, `${plan.experiment} · ${fmt(plan.duration_s, 1)} s · ${plan.n_commands} commands`),
        h("p.muted.small", {}, `plan ${plan.id} · parameters ${JSON.stringify(plan.parameters)}`),
        h("table.list", {}, ...plan.segments.map((s) => h("tr", {}, h("td", {}, s.name), h("td", {}, s.kind), h("td", {}, `${fmt(s.t_start_s, 1)}–${fmt(s.t_end_s, 1)} s`)))),
        h("table.list", {}, ...Object.entries(plan.metrics).map(([k, v]) => h("tr", {}, h("th", {}, k), h("td", {}, fmt(v, 6))))));
      scheduleForm(schedule, ctx, plan);
    })
    .catch((e: Error) => {
      clear(info);
      info.append(h("p.error", {}, e.message));
    });
  return () => {
    window.clearInterval(timer);
    view.dispose();
  };
}

function scheduleForm(box: HTMLElement, ctx: Ctx, plan: PlanPublic): void {
  clear(box);
  box.append(h("h3", {}, "Schedule a pass"));
  if (!ctx.canCommand) {
    box.append(h("p.muted", {}, "Scheduling needs the operator role."));
    return;
  }
  const now = ctx.socket.groundNowMs();
  const iso = (ms: number): string => new Date(Math.round(ms / 1000) * 1000).toISOString().replace(".000Z", "Z");
  // A window that holds the plan with a margin, and at least a 20-minute contact.
  const windowS = Math.max(1200, plan.duration_s + 300);
  const name = h("input", { type: "text", name: "name", value: `${plan.experiment}-${new Date(now).toISOString().slice(11, 16).replace(":", "")}`, "data-test": "pass-name-input" });
  const aos = h("input", { type: "text", name: "aos", value: iso(now + 60_000), "data-test": "aos-input" });
  const los = h("input", { type: "text", name: "los", value: iso(now + 60_000 + windowS * 1000), "data-test": "los-input" });
  const relay = h("input", { type: "text", name: "relay", value: "TDRS" });
  const out = h("p", { "data-test": "schedule-result" });
  const submit = h("button.primary", { type: "submit", "data-test": "schedule-submit" }, "Schedule pass");
  const form = h("form.schedule", {},
    h("label", {}, "Pass name", name), h("label", {}, "AOS (UTC, ISO-8601)", aos),
    h("label", {}, "LOS (UTC, ISO-8601)", los), h("label", {}, "Relay", relay), submit, out);
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    submit.disabled = true;
    out.className = "";
    out.textContent = "Scheduling…";
    post<PassPublic>("/api/passes", {
      plan_id: plan.id, name: name.value.trim(), aos_time: aos.value.trim(), los_time: los.value.trim(), relay: relay.value.trim(),
    })
      .then((p) => {
        clear(out);
        out.className = "ok";
        out.append(`Scheduled ${p.name}. `, h("a", { href: `#/live/${p.id}`, "data-test": "open-live" }, "Open the live view"));
      })
      .catch((e: Error) => {
        out.className = "error";
        out.textContent = e.message;
      })
      .finally(() => (submit.disabled = false));
  });
  box.append(form);
}
