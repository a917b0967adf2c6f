// After the pass: what it delivered (the summary), the server's report and recording when
// this server offers them (its OpenAPI document lists them; otherwise "not available"),
// predicted-vs-flown overlays of the whole archive, downloads (JSON of the archive, PNG of
// every plot), and replay: the server's replay over the console websocket (play, pause,
// speed, step and seek; docs/console.md), its telemetry drawn on the same plots, and the
// pass's alarms (all of them: a review) marked on the plots of what they watch.

import { AlarmBook } from "../alarms";
import {
  get, getAll, passRawFields, planRobot, planRules, post, storedToken,
  type CommandPublic, type PassPublic, type PlanDocument,
} from "../api";
import type { Ctx } from "../main";
import type { ReplayOpenedMsg, ReplayStateMsg } from "../protocol.gen";
import { RAW_FIELDS, TelemetryStore } from "../store";
import { clear, fmt, h, utc } from "../ui";
import { stateBadge, stateReason } from "./control";
import { PassView, predictionColumns } from "./passview";

const OPTIONAL = [
  { path: "/api/passes/{pass_id}/report", label: "Report (JSON)", file: "report.json", suffix: "report" },
  { path: "/api/passes/{pass_id}/report.html", label: "Report (HTML)", file: "report.html", suffix: "report.html" },
  { path: "/api/passes/{pass_id}/recording.mcap", label: "Recording (MCAP)", file: "recording.mcap", suffix: "recording.mcap" },
];

/** The replay speeds offered: real time ×N, as fast as possible, step by step. */
const SPEEDS = [
  { value: "rt:1", label: "1×" },
  { value: "rt:10", label: "10×" },
  { value: "rt:60", label: "60×" },
  { value: "rt:300", label: "300×" },
  { value: "afap", label: "As fast as possible" },
  { value: "step", label: "Step by step" },
];

function speedSpec(value: string): Record<string, unknown> {
  if (value === "afap") return { mode: "as_fast_as_possible", batch_frames: 100 };
  if (value === "step") return { mode: "step" };
  return { mode: "real_time", factor: Number(value.slice(3)) };
}

/** Download a protected resource (the token goes in a header, never in the URL). */
async function download(url: string, filename: string): Promise<void> {
  const token = storedToken();
  const r = await fetch(url, { headers: token ? { Authorization: `Bearer ${token}` } : {} });
  if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
  saveBlob(await r.blob(), filename);
}

function saveBlob(blob: Blob, filename: string): void {
  const a = h("a", { href: URL.createObjectURL(blob), download: filename });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(a.href), 10_000);
}

export function reportPage(root: HTMLElement, ctx: Ctx, params: string[]): () => void {
  const passId = params[0];
  if (!passId) {
    root.append(h("p.muted", {}, "Choose a pass in Passes to see its report."));
    return () => undefined;
  }
  const title = h("h1", {}, "Pass report");
  const summary = h("div.panel", { "data-test": "summary" }, h("p.muted", {}, "Loading…"));
  const artefacts = h("div.panel", { "data-test": "artefacts" }, h("h3", {}, "Report and downloads"));
  const serverReport = h("div.panel.wide", { "data-test": "server-report" });
  const play = h("button", { type: "button", "data-test": "replay-play", disabled: true }, "▶ Play");
  const step = h("button", { type: "button", "data-test": "replay-step", disabled: true, title: "One frame" }, "▶| Step");
  const speed = h("select", { "data-test": "replay-speed" },
    ...SPEEDS.map((s) => h("option", { value: s.value, selected: s.value === "rt:10" }, s.label)));
  const scrub = h("input", { type: "range", min: "0", max: "1000", value: "0", step: "any", "data-test": "replay-scrub", disabled: true });
  const tLabel = h("span.mono", { "data-test": "replay-time" }, "Opening the replay…");
  root.append(
    h("div.passbar", {}, title, h("span.spacer"), h("a", { href: `#/live/${passId}` }, "Live view")),
    h("section.status", {}, summary, artefacts),
    serverReport,
    h("div.replaybar", {}, h("b", {}, "Replay "), play, step, speed, scrub, tLabel),
  );
  const view = new PassView(root, ctx.paths);
  let disposed = false;
  const alarms = new AlarmBook({ passId, activeOnly: false });
  let alarmEpochNs: number | null = null;
  const offAlarms = alarms.onChange(() => view.setAlarms(alarms.list(), alarmEpochNs));
  const offAlarmMessages = ctx.on((m) => {
    if (m.type === "alarm") alarms.apply(m.alarm);
  });
  /** The whole archive (REST): the predicted-vs-flown overlay, and the history before a seek. */
  let archive: TelemetryStore | null = null;
  /** What the replay has shown: the archive before the seek point, then the replay's frames. */
  let shown: TelemetryStore | null = null;
  let epochNs = 0;
  let range: [number, number] = [0, 0]; // onboard ns, the seekable range
  let playing = false;
  let finished = false;
  /** The seq of the last seek's answer: data at or below it is from before the seek. */
  let seekSeq = -1;
  /** Where to seek after the replay was opened again (reconnect), onboard ns. */
  let resumeNs: number | null = null;
  let received = 0;
  let redraw = 0;

  const planT = (ns: number): number => (ns - epochNs) / 1e9;
  const showPosition = (ns: number): void => {
    const t = planT(ns);
    scrub.value = String(((ns - range[0]) / Math.max(range[1] - range[0], 1)) * 1000);
    root.dataset.replayT = t.toFixed(3);
    view.setMarker(t);
  };
  const scheduleRedraw = (): void => {
    if (redraw) return;
    redraw = requestAnimationFrame(() => {
      redraw = 0;
      if (disposed || !shown) return;
      view.showStore(shown);
      root.dataset.replayShown = String(shown.count);
    });
  };
  /** The replay's plots restart at onboard ``ns``: the archive's frames before it, then
   * whatever the replay sends. */
  const restartAt = (ns: number | null): void => {
    const s = new TelemetryStore(epochNs);
    if (archive) s.addFrames(archive.framesBefore(ns ?? Number.POSITIVE_INFINITY));
    shown = s;
    scheduleRedraw();
  };
  const setPlaying = (value: boolean): void => {
    playing = value;
    play.textContent = value ? "❚❚ Pause" : "▶ Play";
    root.dataset.replaying = String(value);
  };

  const applyState = (m: ReplayStateMsg | ReplayOpenedMsg): void => {
    setPlaying(m.playing);
    finished = m.finished;
    const position = m.position;
    const frames = m.frames;
    const playheadNs = m.playhead_ns;
    resumeNs = playheadNs;
    root.dataset.replayReason = m.reason;
    root.dataset.replayPosition = String(position);
    root.dataset.replayFrames = String(frames);
    root.dataset.replayNextNs = String(m.next_generation_time_ns ?? "");
    root.dataset.replayStates = String(Number(root.dataset.replayStates ?? 0) + 1);
    tLabel.textContent = `t = ${fmt(m.playhead_t_s, 1)} s · frame ${Math.min(position, frames)} / ${frames}${finished ? " · end" : ""}`;
    showPosition(playheadNs);
  };

  const replay = ctx.socket.openReplay(passId, { paused: true, speed: speedSpec("rt:10"), fields: [...RAW_FIELDS] }, {
    opened(m) {
      const resume = resumeNs; // the playhead before a reconnect, if any
      epochNs = m.epoch_ns;
      range = [m.first_generation_time_ns, m.last_generation_time_ns];
      root.dataset.replayId = m.replay_id;
      root.dataset.replayFirstNs = String(range[0]);
      root.dataset.replayLastNs = String(range[1]);
      play.disabled = false;
      step.disabled = false;
      scrub.disabled = false;
      applyState(m);
      const wanted = speed.value;
      if (wanted !== "rt:10") replay.request("replay_speed", { speed: speedSpec(wanted) });
      if (resume !== null && resume > range[0]) seekTo(resume);
    },
    state(m) {
      if (m.reason === "seek") {
        seekSeq = m.seq;
        root.dataset.replaySeeks = String(Number(root.dataset.replaySeeks ?? 0) + 1);
        restartAt(m.next_generation_time_ns ?? null);
      }
      applyState(m);
    },
    data(m) {
      if (m.seq <= seekSeq || m.type !== "telemetry") return;
      const columns = m.columns;
      const gen = columns.generation_time_ns;
      if (gen.length === 0) return;
      if (!shown) restartAt(gen[0]);
      if (root.dataset.replayFirstRow === undefined) root.dataset.replayFirstRow = String(m.row);
      received += gen.length;
      root.dataset.replayReceived = String(received);
      root.dataset.replayLastRow = String(m.row + gen.length - 1);
      shown!.addColumns(columns, false);
      const last = shown!.latest;
      if (last) view.showFrame(last);
      showPosition(gen[gen.length - 1]);
      scheduleRedraw();
    },
    error(reason) {
      tLabel.textContent = `Replay: ${reason}`;
    },
    lost() {
      play.disabled = true;
      step.disabled = true;
      scrub.disabled = true;
      setPlaying(false);
      tLabel.textContent = "Replay: the console reconnects…";
    },
  });

  const seekTo = (ns: number): void => {
    const target = Math.round(Math.min(Math.max(ns, range[0]), range[1]));
    root.dataset.replaySeekNs = String(target);
    delete root.dataset.replayFirstRow;
    replay.request("replay_seek", { onboard_time_ns: target });
  };
  scrub.addEventListener("input", () => {
    seekTo(range[0] + (Number(scrub.value) / 1000) * (range[1] - range[0]));
  });
  play.addEventListener("click", () => {
    if (playing) {
      replay.request("replay_pause");
      return;
    }
    if (finished) seekTo(range[0]); // from the start again
    replay.request("replay_play");
  });
  step.addEventListener("click", () => {
    if (finished) return;
    replay.request("replay_step");
  });
  speed.addEventListener("change", () => replay.request("replay_speed", { speed: speedSpec(speed.value) }));

  const load = async (): Promise<void> => {
    const pass = await get<PassPublic>(`/api/passes/${passId}`);
    title.textContent = `Pass report: ${pass.name}`;
    alarmEpochNs = pass.epoch_ns ?? 0;
    if (ctx.paths.has("/api/alarms")) void alarms.load();
    const [sum, commands, doc] = await Promise.all([
      get<Record<string, unknown>>(`/api/passes/${passId}/summary`),
      getAll<CommandPublic>(`/api/passes/${passId}/commands`),
      get<PlanDocument>(`/api/plans/${pass.plan_id}/document`).catch(() => null),
    ]);
    clear(summary);
    summary.append(h("h3", {}, stateBadge(pass, "pass-state"), ` AOS ${utc(pass.aos_time)} · LOS ${utc(pass.los_time)} `, stateReason(pass)),
      outcomeLine(sum),
      h("table.list", {}, ...Object.entries(sum).filter(([k]) => !["pass_id", "name"].includes(k)).map(([k, v]) =>
        h("tr", {}, h("th", {}, k), h("td", {}, typeof v === "object" && v !== null ? JSON.stringify(v) : String(v ?? "—"))))));
    if (doc) view.setPrediction(predictionColumns(doc));
    view.setRobot(doc ? planRobot(doc) : null);
    view.setFlightRules(planRules(null, doc));
    // The whole archive, page by page.
    const s = new TelemetryStore(pass.epoch_ns ?? 0);
    const rows: unknown[] = [];
    const fields = (await passRawFields(passId)).join(",");
    let t0 = 0;
    for (;;) {
      const page = await get<{ rows: { seq: number; generation_time_ns: number; values: Record<string, unknown> }[]; truncated: boolean }>(
        `/api/passes/${passId}/telemetry?t0=${t0}&limit=10000&fields=${fields}`);
      const got = page.rows ?? [];
      s.addRows(got);
      rows.push(...got);
      if (!page.truncated || got.length === 0) break;
      t0 = got[got.length - 1].generation_time_ns + 1;
    }
    archive = s;
    if (shown === null) view.showStore(s); // until the replay shows something
    root.dataset.frames = String(s.count);
    if (s.count === 0) tLabel.textContent = "No archived telemetry: nothing to replay.";
    // Downloads built here: the archive as JSON, every plot as PNG.
    const json = h("button", { type: "button", "data-test": "download-json" }, "Telemetry + commands (JSON)");
    json.addEventListener("click", () =>
      saveBlob(new Blob([JSON.stringify({ pass, summary: sum, commands, telemetry: rows })], { type: "application/json" }), `${pass.name}.json`));
    const png = h("button", { type: "button", "data-test": "download-png" }, "Plots (PNG)");
    png.addEventListener("click", () => {
      for (const canvas of root.querySelectorAll<HTMLCanvasElement>(".passview canvas")) {
        const title = canvas.closest(".plot")?.querySelector(".u-title")?.textContent ?? canvas.closest(".phase, .view3d-holder")?.querySelector(".phase-title")?.textContent ?? "plot";
        canvas.toBlob((b) => b && saveBlob(b, `${pass.name}-${title.replace(/[^A-Za-z0-9]+/g, "_")}.png`));
      }
    });
    artefacts.append(h("div.actions", {}, json, png));
    // The server's own report and recording, when this server has them.
    const list = h("ul.artefacts");
    for (const o of OPTIONAL) {
      if (ctx.paths.has(o.path)) {
        const b = h("button.link", { type: "button", "data-test": `get-${o.suffix}` }, o.label);
        const url = `/api/passes/${passId}/${o.suffix}`;
        b.addEventListener("click", () => void download(url, `${pass.name}-${o.file}`).catch((e: Error) => (b.textContent = e.message)));
        list.append(h("li", {}, b));
      } else {
        list.append(h("li.unavailable", { "data-test": `na-${o.suffix}` }, `${o.label}: not available on this server`));
      }
    }
    artefacts.append(list);
    serverReportSection(serverReport, ctx, pass).catch((e: Error) =>
      serverReport.append(h("p.error", {}, `Server report: ${e.message}`)));
  };
  load().catch((e: Error) => {
    clear(summary);
    summary.append(h("p.error", {}, e.message));
  });

  return () => {
    disposed = true;
    cancelAnimationFrame(redraw);
    replay.close();
    offAlarms();
    offAlarmMessages();
    view.dispose();
  };
}

interface ReportTable {
  id: string;
  title: string;
  columns: string[];
  rows: (number | string | boolean | null)[][];
  notes: string[];
}

const cell = (v: number | string | boolean | null): string =>
  v === null ? "—" : typeof v === "number" ? (Number.isInteger(v) ? String(v) : v.toPrecision(5)) : String(v);

/** The server's report (analyses as tables, and figures) when this server offers it. With
 * no analyses yet, an operator may run them; a viewer is told they have not been run. */
async function serverReportSection(box: HTMLElement, ctx: Ctx, pass: PassPublic): Promise<void> {
  clear(box);
  box.append(h("h3", {}, "Server report: predicted against flown"));
  const hasReport = ctx.paths.has("/api/passes/{pass_id}/report");
  const hasAnalyses = ctx.paths.has("/api/passes/{pass_id}/analyses");
  if (!hasReport) {
    box.append(h("p.unavailable", { "data-test": "report-na" }, "Not available on this server (GET /api/passes/{id}/report is not offered)."));
    return;
  }
  if (hasAnalyses) {
    const analyses = await get<{ count: number }>(`/api/passes/${pass.id}/analyses`);
    if (analyses.count === 0) {
      box.append(h("p.unavailable", { "data-test": "report-none" }, "No analyses have been run for this pass yet."));
      if (ctx.canCommand && ["complete", "aborted", "safed", "los"].includes(pass.state)) {
        const run = h("button.primary", { type: "button", "data-test": "run-analyses" }, "Run the analyses");
        run.addEventListener("click", () => {
          run.disabled = true;
          run.textContent = "Analysing (seconds for a whole pass)…";
          post(`/api/passes/${pass.id}/analyses`, {})
            .then(() => serverReportSection(box, ctx, pass).catch((e: Error) => box.append(h("p.error", {}, e.message))))
            .catch((e: Error) => {
              run.disabled = false;
              run.textContent = "Run the analyses";
              box.append(h("p.error", {}, e.message));
            });
        });
        box.append(run);
      }
      return;
    }
  }
  const report = await get<{ tables: ReportTable[]; figures: string[] }>(`/api/passes/${pass.id}/report`);
  const tables = h("div.report-tables", { "data-test": "report-tables" });
  for (const t of report.tables) {
    tables.append(
      h("h4", {}, t.title),
      h("table.list", {}, h("tr", {}, ...t.columns.map((c) => h("th", {}, c))),
        ...t.rows.map((r) => h("tr", {}, ...r.map((v) => h("td", {}, cell(v)))))),
      ...t.notes.map((n) => h("p.muted.small", {}, n)));
  }
  box.append(tables);
  const figures = h("div.figures", { "data-test": "report-figures" });
  box.append(figures);
  const token = storedToken();
  for (const name of report.figures) {
    // Figures need the token: fetched with it, shown from a blob URL.
    fetch(`/api/passes/${pass.id}/report/figures/${encodeURIComponent(name)}.png`, { headers: token ? { Authorization: `Bearer ${token}` } : {} })
      .then((r) => (r.ok ? r.blob() : Promise.reject(new Error(`HTTP ${r.status}`))))
      .then((b) => figures.append(h("figure", {}, h("img", { src: URL.createObjectURL(b), alt: name }), h("figcaption.muted.small", {}, name))))
      .catch((e: Error) => figures.append(h("p.unavailable", {}, `figure ${name}: ${e.message}`)));
  }
}

/** The pass's outcome once it has ended (server/services/summary.py): ``nominal`` only when
 * every command executed at its tag, ``degraded`` with the counts otherwise. */
function outcomeLine(sum: Record<string, unknown>): HTMLElement | string {
  const outcome = sum.outcome;
  if (outcome !== "nominal" && outcome !== "degraded") return "";
  return h("p.outcome", { "data-test": "pass-outcome", "data-outcome": outcome },
    h(`span.badge.${outcome === "nominal" ? "pass" : "fail"}`, {}, outcome.toUpperCase()), " ",
    String(sum.outcome_text ?? "").replace(/^(nominal|degraded): /, ""));
}
