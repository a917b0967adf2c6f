// The timeline (docs/console.md, "Timeline and countdown"): a mission's computed contact
// windows over a span, one lane per relay, each window a bar from AOS to LOS with its net
// time (what a pass may use) inside and its times marked; the passes scheduled in those
// windows placed in them, coloured by state (a click opens the pass); passes given by hand
// in a lane of their own; the ground's "now". Below, every window as a row with its
// numbers; an operator schedules a pass of a stored plan into one from its row
// (./timeline_schedule.ts). The mission and the span (start, hours) are chosen at the top
// and kept in the address (#/timeline/MISSION/START/HOURS).

import {
  ApiError, get, getAll,
  type MissionPublic, type MissionsPublic, type PassPublic, type WindowPublic, type WindowsPublic,
} from "../api";
import type { Ctx } from "../main";
import { clear, fmt, h } from "../ui";
import { groundNow, utcText } from "../windows";
import { WindowScheduler } from "./timeline_schedule";

const SVG = "http://www.w3.org/2000/svg";
const GUTTER = 130; // the lanes' labels (px)
const PAD_RIGHT = 16;
const AXIS_H = 36;
const LANE_H = 50;
/** Tick steps (minutes), the first that leaves this many px between ticks. */
const TICK_STEPS_MIN = [5, 10, 15, 30, 60, 120, 180, 360, 720, 1440];
const MIN_TICK_PX = 80;
/** A pass is in a listed window when the relay is the same and the AOS within this (ms). */
const SAME_WINDOW_MS = 1000;
/** An ISO 8601 time with its UTC offset, as the server takes it. */
const ISO_WITH_ZONE = /^\d{4}-\d{2}-\d{2}T\d{2}:\d{2}(:\d{2}(\.\d+)?)?(Z|[+-]\d{2}:\d{2})$/;

type Attrs = Record<string, string | number>;

function s<K extends keyof SVGElementTagNameMap>(tag: K, attrs: Attrs = {}, ...children: (Node | string)[]): SVGElementTagNameMap[K] {
  const el = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, String(v));
  for (const c of children) el.append(c);
  return el;
}

/** What a pass's bar says in ``px``: its name and state, or what of it fits (about 6.5 px
 * a character at 11 px; the tooltip has it all). */
function passLabel(p: PassPublic, px: number): string {
  const full = `${p.name} · ${p.state.toUpperCase()}`;
  const fits = Math.floor((px - 6) / 6.5);
  if (full.length <= fits) return full;
  const state = p.state.toUpperCase();
  return state.length <= fits ? state : "";
}

const hms = (ms: number): string => new Date(ms).toISOString().slice(11, 19);
const minutes = (seconds: number): string => `${fmt(seconds / 60, 1)} min`;

/** The default span's start: an hour before the ground's now, on the hour, when the
 * mission's elements reach it; else their epoch. */
function defaultStart(mission: MissionPublic, nowMs: number, hours: number): string {
  const from = Date.parse(mission.windows_from);
  const until = Date.parse(mission.windows_until);
  const start = Math.floor((nowMs - 3600_000) / 3600_000) * 3600_000;
  if (start >= from && start + hours * 3600_000 <= until) return new Date(start).toISOString().replace(".000Z", "Z");
  return new Date(Date.parse(mission.epoch)).toISOString().replace(".000Z", "Z");
}

export function timelinePage(root: HTMLElement, ctx: Ctx, params: string[]): () => void {
  let disposed = false;
  let missions: MissionPublic[] = [];
  let maxHours = 168;
  let shown: { mission: MissionPublic; startMs: number; hours: number; windows: WindowPublic[] } | null = null;
  let passes: PassPublic[] = [];

  const missionSel = h("select", { "data-test": "tl-mission", name: "mission" });
  const startIn = h("input", { type: "text", "data-test": "tl-start", name: "start", size: 26, spellcheck: "false",
    title: "ISO 8601 with its UTC offset, e.g. 1999-09-30T00:00:00Z" });
  const hoursIn = h("input", { type: "number", "data-test": "tl-hours", name: "hours", min: 0.25, step: "any", style: "width:6em" });
  const nowBtn = h("button", { type: "button", "data-test": "tl-now-button", title: "an hour before the ground's now" }, "Now");
  const epochBtn = h("button", { type: "button", "data-test": "tl-epoch-button", title: "the elements' epoch" }, "Epoch");
  const showBtn = h("button.primary", { type: "submit", "data-test": "tl-show" }, "Show");
  const formError = h("p.error", { role: "alert", "data-test": "tl-error" });
  // novalidate: the page says what is wrong with a value in words (the browser would only
  // refuse to submit)
  const form = h("form.tl-form", { novalidate: true },
    h("label.inline", {}, "Mission ", missionSel),
    h("label.inline", {}, "Start (UTC) ", startIn),
    h("label.inline", {}, "Hours ", hoursIn),
    nowBtn, epochBtn, showBtn);
  const summary = h("p.small", { "data-test": "tl-summary" });
  const chart = h("div.tl-chart", { "data-test": "tl-chart" });
  const table = h("table.list.tl-table", { "data-test": "tl-table" });
  const schedulePanel = h("div.panel", { "data-test": "tl-schedule-panel" });
  root.append(h("h1", {}, "Timeline"), form, formError, summary, chart, schedulePanel, h("h3", {}, "Windows"), table);
  const scheduler = new WindowScheduler(schedulePanel, () => reloadPasses());

  const selected = (): MissionPublic | undefined => missions.find((m) => m.name === missionSel.value);

  nowBtn.addEventListener("click", () => {
    const m = selected();
    if (m) startIn.value = defaultStart(m, groundNow(ctx.socket).ms, Number(hoursIn.value) || 24);
  });
  epochBtn.addEventListener("click", () => {
    const m = selected();
    if (m) startIn.value = new Date(Date.parse(m.epoch)).toISOString().replace(".000Z", "Z");
  });
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    show();
  });

  const fail = (text: string): void => {
    summary.textContent = text;
    summary.className = "error";
  };

  // --- the span ---------------------------------------------------------------------------
  function show(): void {
    formError.textContent = "";
    scheduler.close();
    const mission = selected();
    const start = startIn.value.trim();
    const hours = Number(hoursIn.value);
    if (!mission) {
      formError.textContent = "Choose a mission.";
      return;
    }
    if (!ISO_WITH_ZONE.test(start) || Number.isNaN(Date.parse(start))) {
      formError.textContent = `Start ${JSON.stringify(start)} is not an ISO 8601 time with its UTC offset (e.g. 1999-09-30T00:00:00Z).`;
      return;
    }
    if (!(hours > 0 && hours <= maxHours)) {
      formError.textContent = `Hours ${hoursIn.value || "(empty)"} is outside (0, ${maxHours}].`;
      return;
    }
    const startMs = Date.parse(start);
    const from = Date.parse(mission.windows_from);
    const until = Date.parse(mission.windows_until);
    if (startMs < from || startMs + hours * 3600_000 > until) {
      formError.textContent = `${mission.name}'s elements reach ${utcText(from)} to ${utcText(until)}: `
        + `choose a span inside (its epoch is ${utcText(Date.parse(mission.epoch))}).`;
      return;
    }
    history.replaceState(null, "", `#/timeline/${encodeURIComponent(mission.name)}/${encodeURIComponent(start)}/${hours}`);
    summary.className = "small muted";
    summary.textContent = `Computing ${mission.name}'s windows…`;
    showBtn.disabled = true;
    const query = `mission=${encodeURIComponent(mission.name)}&start=${encodeURIComponent(start)}&hours=${hours}`;
    Promise.all([get<WindowsPublic>(`/api/windows?${query}`), getAll<PassPublic>("/api/passes")])
      .then(([body, all]) => {
        if (disposed) return;
        shown = { mission, startMs, hours, windows: body.data };
        passes = all;
        render();
      })
      .catch((e: Error) => fail(e instanceof ApiError ? `${e.message} (${e.code})` : e.message))
      .finally(() => (showBtn.disabled = false));
  }

  const reloadPasses = (): void => {
    getAll<PassPublic>("/api/passes")
      .then((all) => {
        if (disposed) return;
        passes = all;
        render();
      })
      .catch(() => undefined);
  };

  // --- drawing ----------------------------------------------------------------------------
  let nowLine: SVGLineElement | null = null;
  let xOf: ((ms: number) => number) | null = null;
  let spanMs: [number, number] | null = null;

  function render(): void {
    if (shown === null) return;
    const { mission, startMs, hours, windows } = shown;
    const endMs = startMs + hours * 3600_000;
    const width = Math.max(640, chart.clientWidth || 1200);
    const plotW = width - GUTTER - PAD_RIGHT;
    const x = (ms: number): number => GUTTER + ((ms - startMs) / (endMs - startMs)) * plotW;
    const clip = (px: number): number => Math.max(GUTTER, Math.min(width - PAD_RIGHT, px));
    xOf = x;
    spanMs = [startMs, endMs];

    // Passes: in this mission's windows, given by hand, or of other missions (counted).
    const inMission = passes.filter((p) => p.window && p.window.mission === mission.name);
    const byHand = passes.filter((p) => !p.window && Date.parse(p.los_time) > startMs && Date.parse(p.aos_time) < endMs);
    const elsewhere = passes.filter((p) => p.window && p.window.mission !== mission.name).length;
    const lanes = mission.relays.map((r) => r.name);
    const handLane = byHand.length > 0;
    const height = AXIS_H + (lanes.length + (handLane ? 1 : 0)) * LANE_H + 4;
    const svg = s("svg", { width, height, viewBox: `0 0 ${width} ${height}`, class: "tl", "data-test": "tl-svg" });

    // The axis: ticks on whole UTC steps, dated at midnight and at the first tick.
    const spanMin = (endMs - startMs) / 60_000;
    const step = (TICK_STEPS_MIN.find((m) => (m / spanMin) * plotW >= MIN_TICK_PX) ?? 1440) * 60_000;
    const axis = s("g", { class: "axis" });
    let first = true;
    for (let t = Math.ceil(startMs / step) * step; t <= endMs; t += step) {
      const px = x(t);
      const iso = new Date(t).toISOString();
      const dated = first || iso.slice(11, 16) === "00:00";
      first = false;
      // A label near the right edge ends at its tick instead of running off the chart.
      const label: Attrs = px > width - 80 ? { x: px - 3, "text-anchor": "end" } : { x: px + 3 };
      axis.append(
        s("line", { x1: px, x2: px, y1: AXIS_H - 6, y2: height, class: "grid" }),
        s("text", { ...label, y: AXIS_H - 20, class: "tick" }, iso.slice(11, 16)),
      );
      if (dated) axis.append(s("text", { ...label, y: AXIS_H - 8, class: "tick date" }, iso.slice(0, 10)));
    }
    svg.append(axis);

    const laneY = (i: number): number => AXIS_H + i * LANE_H;
    lanes.forEach((relay, i) => {
      svg.append(
        s("rect", { x: 0, y: laneY(i), width, height: LANE_H, class: `lane ${i % 2 ? "odd" : "even"}` }),
        s("text", { x: 8, y: laneY(i) + LANE_H / 2 + 4, class: "lane-label", "data-test": "tl-lane", "data-relay": relay }, relay),
      );
    });
    if (handLane) {
      const i = lanes.length;
      svg.append(
        s("rect", { x: 0, y: laneY(i), width, height: LANE_H, class: "lane hand" }),
        s("text", { x: 8, y: laneY(i) + LANE_H / 2 + 4, class: "lane-label", "data-test": "tl-lane", "data-relay": "" }, "given by hand"),
      );
    }

    // The windows: AOS..LOS, the net time inside, the times marked where they fit.
    const occupant = new Map<number, PassPublic[]>();
    windows.forEach((w, index) => {
      const lane = lanes.indexOf(w.relay);
      if (lane < 0) return;
      const aos = Date.parse(w.aos_time);
      const los = Date.parse(w.los_time);
      const netA = Date.parse(w.net_start_time);
      const netB = Date.parse(w.net_end_time);
      const y = laneY(lane);
      const x0 = clip(x(aos));
      const x1 = clip(x(los));
      const inside = inMission.filter((p) => p.window!.relay === w.relay && Math.abs(Date.parse(p.window!.aos_time) - aos) < SAME_WINDOW_MS);
      occupant.set(index, inside);
      const g = s("g", {
        class: `window${inside.length ? " used" : ""}`, "data-test": "tl-window", "data-index": index,
        "data-relay": w.relay, "data-aos": w.aos_time, "data-los": w.los_time,
        "data-net-start": w.net_start_time, "data-net-end": w.net_end_time,
        "data-passes": inside.map((p) => p.id).join(" "),
      });
      g.append(
        s("title", {}, `${w.relay}: AOS ${utcText(aos)}, LOS ${utcText(los)} (${minutes(w.duration_s)}); `
          + `net ${hms(netA)}–${hms(netB)}Z (${minutes(w.net_s)}); range ${fmt(w.min_range_km, 0)}–${fmt(w.max_range_km, 0)} km; `
          + `light time ${fmt(w.light_time_min_s * 1000, 0)}–${fmt(w.light_time_max_s * 1000, 0)} ms`),
        s("rect", { x: x0, y: y + 6, width: Math.max(1, x1 - x0), height: LANE_H - 12, rx: 3, class: "bar" }),
        s("rect", { x: clip(x(netA)), y: y + 10, width: Math.max(1, clip(x(netB)) - clip(x(netA))), height: LANE_H - 20, class: "net" }),
        // A LOS past the span's end is marked dashed at the end (the window goes on).
        s("line", { x1: clip(x(aos)), x2: clip(x(aos)), y1: y + 3, y2: y + LANE_H - 3, class: "mark aos" }),
        s("line", { x1: x1, x2: x1, y1: y + 3, y2: y + LANE_H - 3, class: `mark los${los > endMs ? " clipped" : ""}` }),
      );
      // Times as text when the bar leaves room (else in the tooltip and the table).
      if (x1 - x0 >= 150) {
        g.append(
          s("text", { x: x0 + 3, y: y + 17, class: "t aos" }, `AOS ${hms(aos)}`),
          s("text", { x: x1 - 3, y: y + 17, class: "t los", "text-anchor": "end" }, `LOS ${hms(los)}`),
        );
        if (inside.length === 0) {
          g.append(s("text", { x: (x0 + x1) / 2, y: y + LANE_H - 13, class: "t net", "text-anchor": "middle" }, `net ${minutes(w.net_s)}`));
        }
      }
      svg.append(g);
    });

    // The passes: each where it runs (its net time), in its relay's lane or the hand lane.
    const drawPass = (p: PassPublic, lane: number, windowIndex: number | null): void => {
      const a = Date.parse(p.aos_time);
      const b = Date.parse(p.los_time);
      if (b <= startMs || a >= endMs) return;
      const y = laneY(lane);
      const x0 = clip(x(a));
      const x1 = clip(x(b));
      const link = s("a", {
        href: `#/live/${p.id}`, class: "pass", "data-test": "tl-pass", "data-pass": p.id, "data-name": p.name,
        "data-state": p.state, "data-window-index": windowIndex ?? "", "data-relay": p.window ? p.window.relay : "",
      });
      link.append(
        s("title", {}, `${p.name}: ${p.state.toUpperCase()}${p.state_reason ? ` (${p.state_reason})` : ""}; `
          + `${utcText(a)} to ${utcText(b)}${p.window ? "" : " (given by hand)"}; click to open`),
        s("rect", { x: x0, y: y + LANE_H - 22, width: Math.max(3, x1 - x0), height: 16, rx: 2, class: `pbar state-${p.state}` }),
        s("text", { x: x0 + 3, y: y + LANE_H - 10, class: "t pname" }, passLabel(p, x1 - x0)),
      );
      svg.append(link);
    };
    for (const p of inMission) {
      const lane = lanes.indexOf(p.window!.relay);
      if (lane < 0) continue;
      const index = [...occupant.entries()].find(([, ps]) => ps.includes(p))?.[0] ?? null;
      drawPass(p, lane, index);
    }
    for (const p of byHand) drawPass(p, lanes.length, null);

    nowLine = s("line", { x1: 0, x2: 0, y1: AXIS_H - 4, y2: height, class: "now", "data-test": "tl-now" });
    svg.append(nowLine);
    clear(chart);
    chart.append(svg);
    moveNow();

    // The summary and the table.
    const perRelay = lanes.map((r) => `${r} ${windows.filter((w) => w.relay === r).length}`).join(" · ");
    summary.className = "small";
    summary.dataset.count = String(windows.length);
    summary.textContent = `${windows.length} window${windows.length === 1 ? "" : "s"} with AOS from ${utcText(startMs)} for ${hours} h `
      + `(${perRelay}); a pass keeps ${mission.aos_margin_s} s after AOS and ${mission.los_margin_s} s before LOS; `
      + `one-way delay ${mission.processing_delay_s} s + the light time. `
      + `${inMission.length} pass${inMission.length === 1 ? "" : "es"} of ${mission.name}`
      + (byHand.length ? `, ${byHand.length} given by hand in the span` : "")
      + (elsewhere ? `; ${elsewhere} of other missions not shown` : "") + ".";
    clear(table);
    const columns = ["#", "Relay", "AOS", "LOS", "Duration", "Net start", "Net end", "Net", "Range km", "Light time ms", "Pass"];
    if (ctx.canCommand) columns.push("");
    table.append(h("tr", {}, ...columns.map((t) => h("th", {}, t))));
    windows.forEach((w, index) => {
      const ps = occupant.get(index) ?? [];
      table.append(h("tr", { "data-test": "tl-row", "data-index": index, "data-relay": w.relay, "data-aos": w.aos_time, "data-los": w.los_time },
        h("td", {}, String(index + 1)),
        h("td", {}, w.relay),
        h("td", { "data-test": "tl-aos" }, utcText(Date.parse(w.aos_time))),
        h("td", { "data-test": "tl-los" }, utcText(Date.parse(w.los_time))),
        h("td", {}, minutes(w.duration_s)),
        h("td", {}, hms(Date.parse(w.net_start_time)) + "Z"),
        h("td", {}, hms(Date.parse(w.net_end_time)) + "Z"),
        h("td", { "data-test": "tl-net" }, minutes(w.net_s)),
        h("td", {}, `${fmt(w.min_range_km, 0)}–${fmt(w.max_range_km, 0)}`),
        h("td", {}, `${fmt(w.light_time_min_s * 1000, 0)}–${fmt(w.light_time_max_s * 1000, 0)}`),
        h("td", {}, ...ps.flatMap((p, i) => [i ? ", " : "", h("a", { href: `#/live/${p.id}`, "data-test": "tl-row-pass" }, `${p.name} (${p.state})`)])),
        ...(ctx.canCommand ? [h("td", {}, scheduleButton(mission.name, w, index))] : []),
      ));
    });
    if (!windows.length) table.append(h("tr", {}, h("td.muted", { colspan: columns.length }, "No window acquires in this span.")));
  }

  function scheduleButton(mission: string, w: WindowPublic, index: number): HTMLElement {
    const button = h("button", { type: "button", "data-test": "tl-schedule", "data-index": index,
      title: `schedule a pass of a stored plan in this window's net time` }, "Schedule…");
    button.addEventListener("click", () => scheduler.open(mission, w, index));
    return button;
  }

  function moveNow(): void {
    if (nowLine === null || xOf === null || spanMs === null) return;
    const now = groundNow(ctx.socket);
    const inside = now.ms >= spanMs[0] && now.ms <= spanMs[1];
    nowLine.setAttribute("visibility", inside ? "visible" : "hidden");
    nowLine.dataset.nowMs = String(now.ms);
    const px = xOf(now.ms);
    nowLine.setAttribute("x1", String(px));
    nowLine.setAttribute("x2", String(px));
  }

  // --- start ------------------------------------------------------------------------------
  if (!ctx.paths.has("/api/missions") || !ctx.paths.has("/api/windows")) {
    fail("This server does not compute contact windows (no GET /api/missions).");
    return () => undefined;
  }
  get<MissionsPublic>("/api/missions")
    .then((body) => {
      if (disposed) return;
      missions = body.data;
      maxHours = body.max_hours;
      hoursIn.max = String(maxHours);
      for (const m of missions) missionSel.append(h("option", { value: m.name }, `${m.name} (${m.vehicle})`));
      for (const u of body.unloadable) missionSel.append(h("option", { value: u.name, disabled: true }, `${u.name}: does not load: ${u.reason}`));
      if (!missions.length) {
        fail("No missions on this server (examples/missions/ or HIKOBOSHI_MISSIONS_DIR).");
        return;
      }
      const mission = missions.find((m) => m.name === params[0]) ?? missions[0];
      missionSel.value = mission.name;
      const hours = params[2] !== undefined && Number(params[2]) > 0 ? Math.min(Number(params[2]), maxHours) : 24;
      hoursIn.value = String(hours);
      startIn.value = params[1] ?? defaultStart(mission, groundNow(ctx.socket).ms, hours);
      show();
    })
    .catch((e: Error) => fail(e.message));

  let reload: number | undefined;
  const off = ctx.on((m) => {
    if (m.type !== "event") return;
    const kind = m.event.kind;
    if (kind === "pass_state" || kind === "pass_scheduled" || kind === "pass_imported") {
      window.clearTimeout(reload);
      reload = window.setTimeout(reloadPasses, 300);
    }
  });
  const offResync = ctx.onResync((topic) => {
    if (topic === "passes" || topic === "events") reloadPasses();
  });
  ctx.socket.subscribe("passes", null);
  ctx.socket.subscribe("events", null);
  const timer = window.setInterval(moveNow, 1000);
  let resize: number | undefined;
  const onResize = (): void => {
    window.clearTimeout(resize);
    resize = window.setTimeout(render, 200);
  };
  window.addEventListener("resize", onResize);
  return () => {
    disposed = true;
    off();
    offResync();
    // Every audit event (command stages among them) is no other page's business.
    ctx.socket.unsubscribe("events", null);
    window.clearInterval(timer);
    window.clearTimeout(reload);
    window.clearTimeout(resize);
    window.removeEventListener("resize", onResize);
  };
}
