// Planning: choose an experiment, edit its parameters, validate (errors inline, at the
// field they name), plan it, preview the predicted trajectories and the 3D motion before
// anything is uplinked, and schedule a pass of it. Operators plan and schedule; viewers
// can preview stored plans.

import {
  ApiError, get, getAll, planRobot, planRules, post,
  type PassPublic, type PlanBrief, type PlanDocument, type PlanPublic, type PlanValidation,
  type RobotPublic,
} from "../api";
import type { Ctx } from "../main";
import { clear, fmt, h } from "../ui";
import { EXPERIMENTS, type ParamSpec } from "./experiments";
import { PassView, predictionColumns } from "./passview";
import { rulesSummary, rulesTable } from "./rules";

const norm = (s: string): string => s.replace(/\s+/g, "").toLowerCase();

/** Parameters that hold one angle per joint: the robot's joint count, its poses offered. */
const isJointList = (spec: ParamSpec): boolean =>
  spec.type === "floats" && (/joints_deg$/.test(spec.name) || /^phi_.*_deg$/.test(spec.name));

/** A description's raw experiment value as the form's text (the server reads it back). */
function asText(value: unknown): string {
  if (Array.isArray(value)) return value.map((v) => asText(v)).join(", ");
  if (typeof value === "boolean") return value ? "true" : "false";
  return String(value);
}

/** ETS-VII as the form offered it before the server listed robots: the catalogue's defaults. */
const BUILT_IN: RobotPublic = {
  name: "ets7", description: "ETS-VII", n_joints: 6, robot_hash: "", default: true,
  joint_limits_deg: [], poses: [], experiments: {}, urdf_url: "/api/model/urdf",
};

/** The parameter's default for ``robot``, as the server plans it when the field is left as
 * it is: the robot's effective default (its description's ``[experiments]`` value, or the one
 * the tool derives for it: ``derived`` when that is not the catalogue's number; null is
 * blank, the robot's own choice), else the catalogue's. From a server that lists no
 * effective defaults, the description's value; there a per-joint list of the catalogue
 * (ETS-VII's six) is blank for a robot of another joint count (the server then takes the
 * robot's own, or says what it needs). */
function defaultFor(spec: ParamSpec, experiment: string, robot: RobotPublic): { text: string; derived: boolean } {
  const effective = (robot.experiment_defaults ?? robot.experiments)[experiment] ?? {};
  const derived = robot.derived_defaults?.[experiment]?.includes(spec.name) ?? false;
  if (spec.name in effective) {
    const value = effective[spec.name];
    const text = value === null || value === undefined ? "" : asText(value);
    // ETS-VII's derived numbers are the catalogue's own: nothing to tell the operator.
    return { text, derived: derived && norm(text) !== norm(spec.default) };
  }
  if (isJointList(spec) && spec.default !== "" && spec.default.split(",").length !== robot.n_joints) return { text: "", derived: false };
  return { text: spec.default, derived: false };
}

export function planPage(root: HTMLElement, ctx: Ctx, params: string[]): () => void {
  const cleanups: (() => void)[] = [];
  if (params[0]) {
    cleanups.push(previewPlan(root, ctx, params[0]));
  } else {
    if (ctx.canCommand) planForm(root, ctx);
    else root.append(h("p.note", { "data-test": "viewer-note" }, "Planning and scheduling need the operator role; you can preview the stored plans."));
    storedPlans(root);
  }
  return () => cleanups.forEach((f) => f());
}

function planForm(root: HTMLElement, ctx: Ctx): void {
  const select = h("select", { "data-test": "experiment" },
    ...Object.entries(EXPERIMENTS).map(([name, e]) => h("option", { value: name }, `${name}: ${e.title}`)));
  const robotSelect = h("select", { "data-test": "robot" }, h("option", { value: BUILT_IN.name }, "ets7 (ETS-VII)"));
  const robotInfo = h("p.muted.small", { "data-test": "robot-info" });
  const fields = h("div.fields");
  const result = h("div.result", { "data-test": "validation" });
  const validate = h("button", { type: "button", "data-test": "validate" }, "Validate");
  const create = h("button.primary", { type: "submit", "data-test": "create-plan" }, "Plan it");
  const form = h("form.planform", {},
    h("h1", {}, "Plan an experiment"),
    h("label", {}, "Robot", robotSelect),
    robotInfo,
    h("label", {}, "Experiment", select),
    fields,
    h("div.actions", {}, validate, create),
    result);
  root.append(form);
  let inputs = new Map<string, { spec: ParamSpec; input: HTMLInputElement | HTMLSelectElement; error: HTMLElement; dflt: string }>();
  let robots: RobotPublic[] = [BUILT_IN];
  const robot = (): RobotPublic => robots.find((r) => r.name === robotSelect.value) ?? BUILT_IN;
  let listError = "";

  const build = (): void => {
    clear(fields);
    clear(result);
    inputs = new Map();
    const r = robot();
    const poses = r.poses.filter((p) => p.joints_deg !== null && p.joints_deg.length === r.n_joints);
    clear(robotInfo);
    if (listError) robotInfo.append(h("span.error", {}, listError));
    robotInfo.append(`${r.name}: ${r.n_joints} joints` +
      (r.poses.length ? `, poses ${r.poses.map((p) => p.name).join(", ")}` : "") +
      (r.description ? ` · ${r.description}` : ""));
    robotInfo.dataset.joints = String(r.n_joints);
    for (const spec of EXPERIMENTS[select.value].params) {
      const { text: dflt, derived } = defaultFor(spec, select.value, r);
      const jointList = isJointList(spec);
      const hint = jointList ? `${r.n_joints} values, or default (the robot's)` : spec.optional ? "default (derived)" : "";
      const choices = spec.type === "bool" ? ["true", "false"] : spec.choices;
      const input = choices
        ? h("select", { name: spec.name }, ...choices.map((c) => h("option", { value: c }, c)))
        : h("input", { type: "text", name: spec.name, value: dflt, spellcheck: "false", placeholder: hint });
      if (choices) input.value = dflt;
      const error = h("span.field-error", { "data-test": `error-${spec.name}`, role: "alert" });
      const unit = jointList
        ? ` (deg, ${r.n_joints} comma-separated)`
        : spec.type === "floats" || spec.type === "strings" ? " (comma-separated)" : "";
      const name = h("span.name", {}, spec.name, h("span.muted.small", {}, unit));
      if (derived) {
        // Not written in the robot's description: the tool's value for this arm.
        const why = "Not in the robot's description: derived by the planner for this robot (docs/robots.md, Experiment defaults)";
        name.append(h("span.muted.small.derived", { "data-test": `derived-${spec.name}`, title: why }, " · derived for this robot"));
        input.title = why;
      }
      const parts: (HTMLElement | string)[] = [name, input];
      if (jointList && poses.length) {
        // The robot's named poses: choosing one writes its joints into the field.
        const pick = h("select.pose", { "data-test": `pose-${spec.name}`, title: "A named pose of the robot" },
          h("option", { value: "" }, "pose…"),
          ...poses.map((p) => h("option", { value: p.name, title: p.description }, `${p.name}${p.description ? `: ${p.description}` : ""}`)));
        pick.addEventListener("change", () => {
          const pose = poses.find((p) => p.name === pick.value);
          if (!pose?.joints_deg) return;
          input.value = pose.joints_deg.map((v) => String(Number(v.toFixed(4)))).join(", ");
          input.dispatchEvent(new Event("input"));
        });
        parts.push(pick);
      }
      parts.push(error);
      fields.append(h("label.field", { "data-field": spec.name }, ...parts));
      inputs.set(spec.name, { spec, input, error, dflt });
      input.addEventListener("input", () => {
        error.textContent = "";
        input.classList.remove("invalid");
      });
    }
  };

  // The robots this server plans for (older servers: ETS-VII only, as before). The fields
  // are built once the robot is known, so that nothing typed is replaced.
  const listed = ctx.paths.has("/api/robots")
    ? get<{ data: RobotPublic[]; count: number }>("/api/robots").then((page) => page.data)
    : Promise.resolve([] as RobotPublic[]);
  fields.append(h("p.muted", {}, "Loading the robots…"));
  void listed
    .catch((e: Error) => {
      listError = `The server did not list its robots (${e.message}): ETS-VII only. `;
      return [] as RobotPublic[];
    })
    .then((list) => {
      if (list.length) {
        robots = list;
        clear(robotSelect);
        for (const r of list) {
          robotSelect.append(h("option", { value: r.name }, `${r.name} (${r.n_joints} joints)${r.default ? " · default" : ""}`));
        }
        robotSelect.value = (list.find((r) => r.default) ?? list[0]).name;
      }
      robotSelect.addEventListener("change", build);
      select.addEventListener("change", build);
      build();
    });

  const body = (): { experiment: string; parameters: Record<string, string>; robot?: string } => {
    const parameters: Record<string, string> = {};
    for (const [name, { input, dflt }] of inputs) {
      const text = input.value.trim();
      if (text === "" || norm(text) === norm(dflt)) continue;
      parameters[name] = text;
    }
    const r = robot();
    // No robot named: ETS-VII, as a server without robots plans.
    return r.default ? { experiment: select.value, parameters } : { experiment: select.value, parameters, robot: r.name };
  };

  /** Per-joint fields hold the robot's joint count (else the field says so, nothing sent). */
  const jointCountErrors = (): { code: string; message: string }[] => {
    const n = robot().n_joints;
    const out: { code: string; message: string }[] = [];
    for (const [name, { spec, input }] of inputs) {
      const text = input.value.trim();
      if (!isJointList(spec) || text === "") continue;
      const count = text.split(",").filter((v) => v.trim() !== "").length;
      if (count !== n) {
        out.push({ code: "joint_count", message: `parameter ${name}: ${robot().name} has ${n} joints, ${count} value${count === 1 ? "" : "s"} given` });
      }
    }
    return out;
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

  /** A plan that plans has its rules table (also when a rule fails: that is why). */
  const showRules = (v: PlanValidation): void => {
    if (v.flight_rules) result.append(rulesSummary(v.flight_rules), rulesTable(v.flight_rules));
  };

  const showSummary = (v: PlanValidation): void => {
    clear(result);
    const s = v.summary!;
    result.append(
      h("p.ok", { "data-test": "validation-ok" }, `Valid: ${fmt(s.duration_s, 1)} s, ${s.n_commands} commands, ${s.segments.length} segments`),
      h("table.list", {}, ...Object.entries(s.metrics).map(([k, val]) => h("tr", {}, h("th", {}, k), h("td", {}, fmt(val, 6))))));
    showRules(v);
  };

  const showInvalid = (v: PlanValidation): void => {
    showErrors(v.errors);
    showRules(v);
  };

  /** Refused only by flight rules: the plan plans, and is stored marked failing so that it
   * can be looked at (as `hikoboshi plan` writes it); the server refuses to start its pass. */
  const onlyRules = (v: PlanValidation): boolean =>
    v.errors.length > 0 && v.errors.every((e) => e.code === "flight_rule_violation");

  const busy = (on: boolean, what: string): void => {
    validate.disabled = on;
    create.disabled = on;
    if (on) {
      clear(result);
      result.append(h("p.muted", {}, what));
    }
  };

  validate.addEventListener("click", () => {
    const counts = jointCountErrors();
    if (counts.length) return showErrors(counts);
    busy(true, "Validating (planning without storing)…");
    post<PlanValidation>("/api/plans/validate", body())
      .then((v) => (v.valid ? showSummary(v) : showInvalid(v)))
      .catch((e: Error) => showErrors([{ code: (e as ApiError).code ?? "error", message: e.message }]))
      .finally(() => busy(false, ""));
  });
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    const counts = jointCountErrors();
    if (counts.length) return showErrors(counts);
    busy(true, "Planning…");
    // Validate first: a refused plan is shown inline rather than as a failed request.
    post<PlanValidation>("/api/plans/validate", body())
      .then(async (v) => {
        if (!v.valid && !onlyRules(v)) return showInvalid(v);
        const plan = await post<PlanPublic>("/api/plans", body());
        location.hash = `#/plan/${plan.id}`;
      })
      .catch((e: Error) => showErrors([{ code: (e as ApiError).code ?? "error", message: e.message }]))
      .finally(() => busy(false, ""));
  });

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
      view.setRobot(planRobot(doc));
      view.showPredictionAsData(pred);
      view.offerRulesCheck(planId, () => undefined);
      view.setFlightRules(planRules(plan, doc));
      view.onShowWorst = (t) => {
        scrub.value = String(duration > 0 ? (1000 * t) / duration : 0);
        show(t);
      };
      // A plan that fails its clearance opens at its worst moment, the pair highlighted.
      const worst = view.clearanceFails ? view.worstTime : null;
      if (worst !== null) view.onShowWorst(worst);
      else show(0);
      clear(info);
      info.append(
        h("h3", {}, `${plan.experiment} · ${fmt(plan.duration_s, 1)} s · ${plan.n_commands} commands`),
        h("p", { "data-test": "plan-robot" }, `robot ${planRobot(doc).name} · ${pred.joints.length} joints`),
        h("p.muted.small", {}, `plan ${plan.id} · parameters ${JSON.stringify(plan.parameters)}`),
        h("table.list", {}, ...plan.segments.map((s) => h("tr", {}, h("td", {}, s.name), h("td", {}, s.kind), h("td", {}, `${fmt(s.t_start_s, 1)}–${fmt(s.t_end_s, 1)} s`)))),
        h("table.list", {}, ...Object.entries(plan.metrics).map(([k, v]) => h("tr", {}, h("th", {}, k), h("td", {}, fmt(v, 6))))));
      scheduleForm(schedule, ctx, plan);
    })
    .catch((e: Error) => {
      clear(info);
      info.append(h("p.error", {}, e.message));
      view.setRobot(null);
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
