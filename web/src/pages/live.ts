// The live pass view: what is happening now (pass state, link, latest values, plots, 3D),
// what comes next (the countdown to the pass's window's AOS and LOS and to the mission's
// next acquisition, on the ground's clock; the plan's next segment, queued commands), and
// whether the spacecraft does what the plan predicted (the prediction under every plot),
// how far ahead the uplink has loaded the onboard schedule (its fill, lead and
// retransmissions, from the link status), and the pass's active alarms (on the plot of what
// they watch; the link's health and the schedule's occupancy in the link panel).
// Stale data is shown as stale (no telemetry for 2 s: a STALE badge and greyed values; no
// link status for two heartbeats: the link is stale); missing frames are gaps.

import {
  ApiError, get, getAll, passRawFields, planRobot, planRules,
  type CommandPublic, type LinkStatus, type PassPublic, type PlanDocument, type Segment,
} from "../api";
import { SEVERITY_COLORS, alarmLimit, alarmSubject, alarmValue, isActive } from "../alarms";
import type { Ctx } from "../main";
import { STAGE_RANK, type CommandStage } from "../protocol.gen";
import type { Message } from "../socket";
import { frameJoints, frameMomentum, frameTargets, TelemetryStore } from "../store";
import { clear, clock, fmt, h } from "../ui";
import { groundNow, NextAcquisition, utcText, windowCountdown } from "../windows";
import { passControls, stateReason } from "./control";
import { renderCommands, renderSchedule } from "./live_panels";
import { PassView, predictionColumns } from "./passview";

/** No telemetry for this long (wall s) while the pass is live: STALE. */
export const TELEMETRY_STALE_S = 2.0;
/** No link message for two heartbeats: the link status is stale (docs/console.md). */
const LINK_STALE_S = 10.0;
const LIVE_STATES = new Set(["aos", "running", "los"]);
/** The alarms the link panel shows (no plot shows what they watch). */
const LINK_PANEL_QUANTITIES = new Set(["frames_behind", "frame_age_s", "schedule_occupancy"]);
/** Whether a pushed stage is one of the server's (command_stages.py, generated). */
const isStage = (stage: unknown): stage is CommandStage =>
  typeof stage === "string" && Object.hasOwn(STAGE_RANK, stage);

async function choosePass(): Promise<PassPublic | null> {
  const status = await get<LinkStatus>("/api/link/status");
  if (status.active_pass_id) return get<PassPublic>(`/api/passes/${status.active_pass_id}`);
  const passes = await getAll<PassPublic>("/api/passes");
  const live = passes.find((p) => LIVE_STATES.has(p.state));
  if (live) return live;
  const next = passes.filter((p) => p.state === "scheduled");
  if (next.length) return next[0];
  return passes.length ? passes[passes.length - 1] : null;
}

export function livePage(root: HTMLElement, ctx: Ctx, params: string[]): () => void {
  let disposed = false;
  let cleanup: (() => void) | null = null;
  const message = h("p.muted", {}, "Finding the pass…");
  root.append(message);
  const load = params[0] ? get<PassPublic>(`/api/passes/${params[0]}`) : choosePass();
  load
    .then((pass) => {
      if (disposed) return;
      if (pass === null) {
        message.textContent = "No pass yet: plan an experiment and schedule a pass in Planning.";
        return;
      }
      if (!params[0]) history.replaceState(null, "", `#/live/${pass.id}`);
      message.remove();
      cleanup = liveView(root, ctx, pass);
    })
    .catch((e: Error) => {
      message.textContent = e instanceof ApiError && e.status === 404 ? `Pass ${params[0]} not found.` : e.message;
      message.className = "error";
    });
  return () => {
    disposed = true;
    cleanup?.();
  };
}

function liveView(root: HTMLElement, ctx: Ctx, initial: PassPublic): () => void {
  let pass = initial;
  let plan: PlanDocument | null = null;
  let store = new TelemetryStore(pass.epoch_ns ?? 0);
  let renderedVersion = -1;
  let link: LinkStatus | null = null;
  let linkAtMs = 0; // performance.now() of the last link status
  let acsMode = "—";
  let bufferQueued: number | null = null;
  let lastCancel: Record<string, unknown> | null = null; // the latest commands_cancelled detail
  const commands = new Map<number, CommandPublic>();
  let commandsDirty = true;
  let windowS: number | null = null; // null: the whole pass

  // --- layout -------------------------------------------------------------------------
  const title = h("h1.passname", { "data-test": "pass-name" });
  const stateBadge = h("span.badge", { "data-test": "pass-state" });
  const stateWhy = h("span.state-reason", { "data-test": "state-reason", hidden: true });
  const countdown = h("span.countdown", { "data-test": "countdown" });
  const nextAos = h("span.next-aos", { "data-test": "next-aos" });
  const groundClock = h("span.ground-clock.small", { "data-test": "ground-clock" });
  const segmentNow = h("span.segment", { "data-test": "segment" });
  const controls = h("span");
  const staleBadge = h("span.badge.stale", { "data-test": "stale", hidden: true }, "STALE");
  const windowSel = h("select", { "data-test": "window" },
    h("option", { value: "" }, "whole pass"),
    h("option", { value: "120" }, "last 2 min"),
    h("option", { value: "30" }, "last 30 s"));
  windowSel.addEventListener("change", () => {
    windowS = windowSel.value ? Number(windowSel.value) : null;
    renderedVersion = -1;
  });
  const reportLink = h("a", { href: `#/report/${pass.id}` }, "Report");
  const top = h("section.passbar", {},
    title, stateBadge, stateWhy, countdown, segmentNow, staleBadge, h("span.spacer"),
    h("label.inline", {}, "Plots: ", windowSel), reportLink, controls);
  const windowBar = h("section.windowbar", { "data-test": "window-bar" }, nextAos, h("span.spacer"), groundClock);

  const linkPanel = h("div.panel.link", { "data-test": "link" });
  const valuesPanel = h("div.panel.values", { "data-test": "values" });
  const timelineCanvas = h("canvas.timeline", { "data-test": "timeline" });
  const stageCounts = h("div.stages", { "data-test": "stage-counts" });
  const nextList = h("ol.cmdlist", { "data-test": "next-commands" });
  const cancelNote = h("p.small.cancel-note", { "data-test": "cancel-note", hidden: true });
  const scheduleBox = h("div.sched", { "data-test": "schedule" });
  const timelinePanel = h("div.panel.commands", {},
    h("h3", {}, "Commands"), stageCounts, timelineCanvas, cancelNote,
    h("h4", {}, "Onboard schedule and uplink"), scheduleBox,
    h("h4", {}, "Next and latest"), nextList);
  const status = h("section.status", {}, linkPanel, valuesPanel, timelinePanel);
  root.append(top, windowBar, status);
  const view = new PassView(root, ctx.paths);
  root.dataset.pass = pass.id;

  // --- data ---------------------------------------------------------------------------
  const loadPlan = (): void => {
    get<PlanDocument>(`/api/plans/${pass.plan_id}/document`)
      .then((doc) => {
        plan = doc;
        view.setPrediction(predictionColumns(doc));
        view.setRobot(planRobot(doc));
        view.offerRulesCheck(pass.plan_id, () => undefined);
        view.setFlightRules(planRules(null, doc));
        // Before any telemetry, a plan that fails its clearance shows its worst moment: why
        // the server will refuse to start this pass.
        if (store.count === 0 && view.clearanceFails) view.showWorstMoment();
        renderedVersion = -1;
      })
      .catch(() => {
        view.setPrediction(null);
        view.setRobot(null);
      });
  };

  let telemetryLoading = false;
  const loadTelemetry = async (): Promise<void> => {
    if (telemetryLoading) return;
    telemetryLoading = true;
    try {
      const target = store;
      const fields = (await passRawFields(pass.id)).join(",");
      let t0 = 0;
      for (;;) {
        const page = await get<{ rows: { seq: number; generation_time_ns: number; values: Record<string, unknown> }[]; truncated: boolean }>(
          `/api/passes/${pass.id}/telemetry?t0=${t0}&limit=10000&fields=${fields}`,
        );
        if (target !== store) return;
        const rows = page.rows ?? [];
        store.addRows(rows);
        if (!page.truncated || rows.length === 0) break;
        t0 = rows[rows.length - 1].generation_time_ns + 1;
      }
    } finally {
      telemetryLoading = false;
    }
  };

  const loadCommands = async (): Promise<void> => {
    const all = await getAll<CommandPublic>(`/api/passes/${pass.id}/commands`);
    // A stage pushed while the REST answer was on its way may be newer: keep the later one.
    for (const c of all) {
      const known = commands.get(c.seq);
      if (known && STAGE_RANK[known.stage] > STAGE_RANK[c.stage]) c.stage = known.stage;
      commands.set(c.seq, c);
    }
    commandsDirty = true;
  };

  const refreshPass = async (): Promise<void> => {
    const fresh = await get<PassPublic>(`/api/passes/${pass.id}`);
    const epochChanged = fresh.epoch_ns !== pass.epoch_ns;
    pass = fresh;
    if (epochChanged && fresh.epoch_ns !== null) {
      store = new TelemetryStore(fresh.epoch_ns);
      renderedVersion = -1;
      void loadTelemetry();
    }
    view.setAlarms(passAlarms(), store.epochNs);
    renderPass();
  };

  let commandReload: number | undefined = undefined;
  const onMessage = (m: Message): void => {
    if (m.type === "telemetry" && m.pass_id === pass.id) {
      const columns = m.columns;
      store.addColumns(columns);
      const modes = columns.acs_mode;
      if (modes?.length) acsMode = modes[modes.length - 1];
      const queued = columns.buffer_queued;
      if (queued?.length) bufferQueued = queued[queued.length - 1];
    } else if (m.type === "link") {
      link = m.status as LinkStatus; // its uplink is a dict on the server: UplinkStatus
      linkAtMs = performance.now();
      renderLink();
    } else if (m.type === "event") {
      const event = m.event;
      if (event.pass_id !== pass.id) return;
      if (event.kind === "pass_state") {
        void refreshPass();
        void loadCommands();
      }
      if (event.kind === "commands_cancelled") {
        // One event for a whole abort (count and seq range, not the seqs): reload.
        lastCancel = event.detail;
        reloadCommandsSoon();
      }
      if (event.kind === "command_stage") {
        const { seq, stage } = event.detail;
        const c = typeof seq === "number" ? commands.get(seq) : undefined;
        if (c) {
          if (isStage(stage)) c.stage = stage;
          commandsDirty = true;
        } else {
          reloadCommandsSoon(); // a command not loaded yet (made at start)
        }
      }
    }
  };
  // Reload once, however many events stream in meanwhile (a debounce that restarts would
  // starve while they do).
  function reloadCommandsSoon(): void {
    if (commandReload !== undefined) return;
    commandReload = window.setTimeout(() => {
      commandReload = undefined;
      void loadCommands();
    }, 300);
  }
  const offMessage = ctx.on(onMessage);
  // The pass's active alarms: on its plots, and the link's in the link panel.
  const passAlarms = () => ctx.alarms.list().filter((a) => a.pass_id === pass.id && isActive(a));
  const offAlarms = ctx.alarms.onChange(() => {
    view.setAlarms(passAlarms(), store.epochNs);
    renderLink();
  });
  view.setAlarms(passAlarms(), store.epochNs);
  const offResync = ctx.onResync((topic, passId) => {
    if (topic === "telemetry" && passId === pass.id) void loadTelemetry();
    if (topic === "commands") void loadCommands();
    if (topic === "passes") void refreshPass();
  });

  ctx.socket.subscribe("link", null);
  ctx.socket.subscribe("passes", null);
  ctx.socket.subscribe("commands", null, {}, () => void loadCommands());
  ctx.socket.subscribe("telemetry", pass.id, { max_rate_hz: 10 }, () => void loadTelemetry());
  get<LinkStatus>("/api/link/status").then((s) => {
    if (link === null) {
      link = s;
      linkAtMs = performance.now();
      renderLink();
    }
  }).catch(() => undefined);
  loadPlan();

  // --- rendering ------------------------------------------------------------------------
  function renderPass(): void {
    title.textContent = pass.name;
    stateBadge.textContent = pass.state.toUpperCase();
    stateBadge.className = `badge state-${pass.state}`;
    stateBadge.title = pass.state_reason ?? "";
    const why = stateReason(pass);
    stateWhy.hidden = why === null;
    stateWhy.textContent = why?.textContent ?? "";
    clear(controls);
    controls.append(passControls(ctx, pass, () => void refreshPass()));
  }

  const onboardNowNs = (): number | null => {
    if (!link?.connected || link.onboard_time_ns === null) return null;
    return link.onboard_time_ns + (performance.now() - linkAtMs) * 1e6 * (link.time_scale ?? 1);
  };

  function renderLink(): void {
    const s = link;
    renderSchedule(scheduleBox, link, pass);
    clear(linkPanel);
    const stale = s !== null && (performance.now() - linkAtMs) / 1000 > LINK_STALE_S;
    linkPanel.classList.toggle("is-stale", stale || !ctx.socket.connected);
    const row = (k: string, v: string | Node, test?: string) =>
      h("div.kv", {}, h("span.k", {}, k), h("span.v", test ? { "data-test": test } : {}, v));
    linkPanel.append(h("h3", {}, "Link ", stale ? h("span.badge.stale", {}, "STALE") : null));
    if (!s) {
      linkPanel.append(h("p.muted", {}, "No link status yet."));
      return;
    }
    const gaps = s.open_gaps ?? [];
    linkPanel.append(
      row("spacecraft", h(`b.${s.connected ? "ok" : "bad"}`, {}, s.connected ? `connected (${s.vehicle ?? "?"})` : "NOT CONNECTED"), "link-connected"),
      row("vehicle mode", s.vehicle_mode === "safe" ? h("b.bad", {}, "SAFE") : (s.vehicle_mode ?? "—"), "link-mode"),
      row("round trip", s.round_trip_s === null ? "—" : `${fmt(s.round_trip_s, 2)} s`, "link-rtt"),
      row("frames behind", s.frames_behind === null ? "—" : String(s.frames_behind), "link-behind"),
      row("open gaps", gaps.length ? gaps.slice(0, 4).map(([a, b]) => `${a}–${b}`).join(", ") + (gaps.length > 4 ? ` +${gaps.length - 4}` : "") : "none", "link-gaps"),
      row("frames missing", String(s.frames_missing ?? 0)),
      row("time scale", s.time_scale === null ? "—" : `${s.time_scale}×`),
      row("console socket", ctx.socket.socketRttMs === null ? "—" : `${fmt(ctx.socket.socketRttMs, 0)} ms`),
    );
    for (const a of passAlarms()) {
      if (!LINK_PANEL_QUANTITIES.has(a.quantity)) continue;
      const severity = a.current_severity ?? a.severity;
      linkPanel.append(h("div.kv.alarm-row", { "data-test": "link-alarm", "data-quantity": a.quantity, "data-severity": severity, style: `--c:${SEVERITY_COLORS[severity]}` },
        h("span.k", {}, `${severity.toUpperCase()} ${alarmSubject(a)}`),
        h("span.v", {}, `${a.state === "cleared" ? "cleared, " : ""}last ${alarmValue(a.last_value, a.unit)} (${alarmLimit(a)})`)));
    }
  }

  // The onboard schedule's fill and lead (from the newest frame's buffer, via the link
  // status) and the running pass's uplink: is the arm's motion loaded far enough ahead?
  function renderValues(stale: boolean): void {
    const f = store.latest;
    valuesPanel.classList.toggle("is-stale", stale);
    clear(valuesPanel);
    const age = store.lastFrameMs === null ? null : (performance.now() - store.lastFrameMs) / 1000;
    valuesPanel.append(h("h3", {}, "Latest telemetry ", h("span.muted.small", {}, age === null ? "(none live)" : `${fmt(age, 1)} s ago`)));
    if (!f) {
      valuesPanel.append(h("p.muted", {}, "No telemetry for this pass yet."));
      return;
    }
    const D = 180 / Math.PI;
    const joints = [...frameJoints(f)];
    const targets = [...frameTargets(f)];
    const table = h("table.vals", {},
      h("tr", {}, h("th", {}, ""), ...joints.map((_, i) => h("th", {}, `J${i + 1}`))),
      h("tr", {}, h("th", {}, "meas °"), ...joints.map((q) => h("td", {}, fmt(q * D, 2)))),
      h("tr", {}, h("th", {}, "cmd °"), ...targets.map((q) => h("td", {}, fmt(q * D, 2)))));
    const n = store.rpy[0].length - 1;
    const body = h("table.vals", {},
      h("tr", {}, h("th", {}, ""), h("th", {}, "x / roll"), h("th", {}, "y / pitch"), h("th", {}, "z / yaw")),
      h("tr", {}, h("th", {}, "attitude °"), ...[0, 1, 2].map((i) => h("td", {}, fmt(store.rpy[i][n], 3)))),
      h("tr", {}, h("th", {}, "rate °/s"), ...[0, 1, 2].map((i) => h("td", {}, fmt(store.rates[i][n], 4)))),
      h("tr", {}, h("th", {}, "wheel N m s"), ...[...frameMomentum(f)].map((m) => h("td", {}, fmt(m, 3)))));
    valuesPanel.append(table, body,
      h("div.kv", {}, h("span.k", {}, "ACS"), h("span.v", {}, acsMode)),
      h("div.kv", {}, h("span.k", {}, "onboard queue"), h("span.v", {}, bufferQueued === null ? "—" : String(bufferQueued))),
      h("div.kv", {}, h("span.k", {}, "frames"), h("span.v", { "data-test": "frame-count" }, String(store.count))));
  }

  function planRange(): [number, number] | null {
    const end = plan ? plan.prediction.t_s[plan.prediction.t_s.length - 1] : null;
    const first = store.first ? store.t(store.first.genNs) : null;
    const last = store.latest ? store.t(store.latest.genNs) : null;
    if (windowS !== null && last !== null) return [last - windowS, last];
    const lo = Math.min(0, first ?? 0);
    const hi = Math.max(end ?? 0, last ?? 0);
    return hi > lo ? [lo, hi] : null;
  }

  function segmentText(tNow: number | null): string {
    if (!plan || tNow === null) return "";
    const segs: Segment[] = plan.segments;
    const now = segs.find((s) => s.t_start_s <= tNow && tNow < s.t_end_s);
    const next = segs.find((s) => s.t_start_s > tNow);
    const scale = link?.time_scale ?? 1;
    return [
      `t = ${fmt(tNow, 1)} s`,
      now ? `now: ${now.name}` : "",
      next ? `next: ${next.name} in ${clock((next.t_start_s - tNow) / scale)}` : "",
    ].filter(Boolean).join(" · ");
  }

  // The next acquisition, from the computed windows of the pass's mission (none for a
  // pass given by hand).
  const acquisition = new NextAcquisition(pass.window?.mission ?? null, ctx.paths);
  const renderCountdown = (): void => {
    // On the ground's UTC clock (the browser's corrected by the console socket's pong).
    const now = groundNow(ctx.socket);
    const cd = windowCountdown(pass, now.ms);
    countdown.textContent = cd.text;
    Object.assign(countdown.dataset, {
      kind: cd.kind, phase: cd.phase, target: cd.target, targetMs: String(cd.targetMs),
      seconds: cd.seconds.toFixed(3), nowMs: String(now.ms), clock: now.synced ? "ground" : "browser",
    });
    const next = acquisition.at(now.ms);
    nextAos.textContent = next.text;
    nextAos.dataset.kind = next.kind;
    nextAos.dataset.nowMs = String(now.ms);
    if (next.kind === "window") {
      Object.assign(nextAos.dataset, { relay: next.window.relay, aosMs: String(next.aosMs), seconds: next.seconds.toFixed(3) });
    } else {
      for (const k of ["relay", "aosMs", "seconds"]) delete nextAos.dataset[k];
    }
    groundClock.textContent = now.synced ? `ground UTC ${utcText(now.ms)}` : `browser clock ${utcText(now.ms)} (no ground time yet)`;
    groundClock.dataset.clock = now.synced ? "ground" : "browser";
  };

  const tick = (): void => {
    renderCountdown();
    const onboard = onboardNowNs();
    const tNow = onboard !== null && pass.epoch_ns !== null && LIVE_STATES.has(pass.state) ? (onboard - pass.epoch_ns) / 1e9 : null;
    segmentNow.textContent = segmentText(tNow);
    // Stale: the pass is live and no frame for TELEMETRY_STALE_S (or the socket is down).
    const age = store.lastFrameMs === null ? Infinity : (performance.now() - store.lastFrameMs) / 1000;
    const stale = LIVE_STATES.has(pass.state) && (age > TELEMETRY_STALE_S || !ctx.socket.connected);
    staleBadge.hidden = !stale;
    staleBadge.textContent = Number.isFinite(age) ? `STALE ${fmt(age, 1)} s` : "STALE: no telemetry";
    root.classList.toggle("telemetry-stale", stale);
    if (store.version !== renderedVersion) {
      renderedVersion = store.version;
      view.setXRange(planRange());
      view.showStore(store);
    }
    view.setMarker(tNow);
    renderValues(stale);
    if (performance.now() - linkAtMs > 1000) renderLink();
    if (commandsDirty || tNow !== null) {
      commandsDirty = false;
      renderCommands(
        { stageCounts, cancelNote, timeline: timelineCanvas, nextList },
        commands.values(),
        lastCancel,
        { pass, plan, range: planRange(), timeScale: link?.time_scale ?? 1 },
        tNow,
      );
    }
  };

  renderPass();
  renderLink();
  // 10 Hz, drawn in the next animation frame: plots, values, countdown.
  let raf = 0;
  const tickMs: number[] = []; // the cost of the last ticks (the bench reads them)
  const timer = window.setInterval(() => {
    if (!raf) raf = requestAnimationFrame(() => {
      raf = 0;
      const t0 = performance.now();
      tick();
      tickMs.push(performance.now() - t0);
      if (tickMs.length > 2000) tickMs.splice(0, 1000);
    });
  }, 100);
  (window as unknown as { hikoboshiLive?: unknown }).hikoboshiLive = {
    pointCounts: () => view.pointCounts(),
    frames: () => store.count,
    store: () => store,
    tickMs: () => tickMs.splice(0),
  };

  return () => {
    window.clearInterval(timer);
    cancelAnimationFrame(raf);
    window.clearTimeout(commandReload);
    acquisition.dispose();
    offMessage();
    offResync();
    ctx.socket.unsubscribe("telemetry", pass.id);
    offAlarms();
    view.dispose();
    delete (window as unknown as { hikoboshiLive?: unknown }).hikoboshiLive;
  };
}
