// After the pass: what it delivered (the summary), the server's report and recording when
// this server offers them (its OpenAPI document lists them; otherwise "not available"),
// predicted-vs-flown overlays of the whole archive, downloads (JSON of the archive, PNG of
// every plot), and replay: play, pause, speed and seek over the archived frames.

import {
  get, getAll, post, storedToken,
  type CommandPublic, type PassPublic, type PlanDocument,
} from "../api";
import type { Ctx } from "../main";
import { RAW_FIELDS, TelemetryStore } from "../store";
import { clear, fmt, h, utc } from "../ui";
import { PassView, predictionColumns } from "./passview";

const OPTIONAL = [
  { path: "/api/passes/{pass_id}/report", label: "Report (JSON)", file: "report.json", suffix: "report" },
  { path: "/api/passes/{pass_id}/report.html", label: "Report (HTML)", file: "report.html", suffix: "report.html" },
  { path: "/api/passes/{pass_id}/recording.mcap", label: "Recording (MCAP)", file: "recording.mcap", suffix: "recording.mcap" },
];

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
  const speed = h("select", { "data-test": "replay-speed" },
    ...[1, 10, 60].map((s) => h("option", { value: String(s), selected: s === 10 }, `${s}×`)));
  const scrub = h("input", { type: "range", min: "0", max: "1000", value: "0", step: "any", "data-test": "replay-scrub", disabled: true });
  const tLabel = h("span.mono", { "data-test": "replay-time" }, "");
  root.append(
    h("div.passbar", {}, title, h("span.spacer"), h("a", { href: `#/live/${passId}` }, "Live view")),
    h("section.status", {}, summary, artefacts),
    serverReport,
    h("div.replaybar", {}, h("b", {}, "Replay "), play, speed, scrub, tLabel),
  );
  const view = new PassView(root, ctx.paths);
  let store: TelemetryStore | null = null;
  let span: [number, number] = [0, 0];
  let t = 0;
  let timer = 0;
  let lastTick = 0;

  const seek = (time: number): void => {
    if (!store) return;
    t = Math.min(Math.max(time, span[0]), span[1]);
    scrub.value = String(((t - span[0]) / Math.max(span[1] - span[0], 1e-9)) * 1000);
    tLabel.textContent = `t = ${fmt(t, 1)} s`;
    root.dataset.replayT = t.toFixed(3);
    view.setMarker(t);
    const f = store.frameAt(t);
    if (f) view.showFrame(f);
  };
  scrub.addEventListener("input", () => {
    seek(span[0] + (Number(scrub.value) / 1000) * (span[1] - span[0]));
  });
  play.addEventListener("click", () => {
    if (timer) {
      window.clearInterval(timer);
      timer = 0;
      play.textContent = "▶ Play";
      root.dataset.replaying = "false";
      return;
    }
    if (t >= span[1]) seek(span[0]);
    play.textContent = "❚❚ Pause";
    root.dataset.replaying = "true";
    lastTick = performance.now();
    timer = window.setInterval(() => {
      const now = performance.now();
      seek(t + ((now - lastTick) / 1000) * Number(speed.value));
      lastTick = now;
      if (t >= span[1]) play.click();
    }, 50);
  });

  const load = async (): Promise<void> => {
    const pass = await get<PassPublic>(`/api/passes/${passId}`);
    title.textContent = `Pass report: ${pass.name}`;
    const [sum, commands, doc] = await Promise.all([
      get<Record<string, unknown>>(`/api/passes/${passId}/summary`),
      getAll<CommandPublic>(`/api/passes/${passId}/commands`),
      get<PlanDocument>(`/api/plans/${pass.plan_id}/document`).catch(() => null),
    ]);
    clear(summary);
    summary.append(h("h3", {}, `${pass.state.toUpperCase()} · AOS ${utc(pass.aos_time)} · LOS ${utc(pass.los_time)}`),
      h("table.list", {}, ...Object.entries(sum).filter(([k]) => !["pass_id", "name"].includes(k)).map(([k, v]) =>
        h("tr", {}, h("th", {}, k), h("td", {}, typeof v === "object" && v !== null ? JSON.stringify(v) : String(v ?? "—"))))));
    if (doc) view.setPrediction(predictionColumns(doc));
    // The whole archive, page by page.
    const s = new TelemetryStore(pass.epoch_ns ?? 0);
    const rows: unknown[] = [];
    let t0 = 0;
    for (;;) {
      const page = await get<{ rows: { seq: number; generation_time_ns: number; values: Record<string, unknown> }[]; truncated: boolean }>(
        `/api/passes/${passId}/telemetry?t0=${t0}&limit=10000&fields=${RAW_FIELDS.join(",")}`);
      const got = page.rows ?? [];
      s.addRows(got);
      rows.push(...got);
      if (!page.truncated || got.length === 0) break;
      t0 = got[got.length - 1].generation_time_ns + 1;
    }
    store = s;
    view.showStore(s);
    root.dataset.frames = String(s.count);
    const first = s.first;
    const last = s.latest;
    if (first && last) {
      span = [s.t(first.genNs), s.t(last.genNs)];
      play.disabled = false;
      scrub.disabled = false;
      seek(span[0]);
    } else {
      tLabel.textContent = "No archived telemetry: nothing to replay.";
    }
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
    window.clearInterval(timer);
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
      if (ctx.canCommand && ["complete", "aborted", "los"].includes(pass.state)) {
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
