// Time plots (uPlot) with the plan's prediction drawn underneath as dashed grey lines, a
// marker for "now" or the replay time, the alarms of what a plot shows (the time in a band
// shaded, the trace coloured there, the thresholds as bands, a tag naming the alarm), and
// the pitch phase plane (a plain canvas).

import uPlot from "uplot";
import "uplot/dist/uPlot.min.css";
import type { Column } from "./store";

export const COLORS = ["#4fc3f7", "#ffb74d", "#81c784", "#e57373", "#ba68c8", "#fff176"];

export interface PredLine {
  x: ArrayLike<number>;
  y: ArrayLike<number>;
}

export interface SeriesSpec {
  label: string;
  color: string;
  dash?: number[];
  width?: number;
}

/** A threshold drawn on a plot: the region beyond it shaded (``above`` or ``below``). */
export interface LimitLevel {
  at: number;
  side: "above" | "below";
}

/** An alarm drawn on a plot (see :func:`timePlot`'s ``setAlarms``). */
export interface AlarmMark {
  /** The series in alarm (0: the first after x); null: the plot as a whole. */
  series: number | null;
  /** Its colour (the worst severity's). */
  color: string;
  /** What the tag over the plot says (short), and its tooltip (the alarm in full). */
  label: string;
  title: string;
  /** For the tests: the alarm's severity and channel. */
  severity: string;
  channel: string;
  /** Plan-time spans in a band (``t1`` null: still in it), each in its band's colour. */
  spans: { t0: number; t1: number | null; color: string }[];
  /** The threshold as a band: ``around`` a reference series (``ref ± halfWidth``: a value
   * that is a distance from it), or levels of the plotted value itself. */
  band?: { kind: "around"; ref: number; halfWidth: number } | { kind: "levels"; levels: LimitLevel[] };
}

export interface TimePlot {
  plot: uPlot;
  el: HTMLElement;
  /** Points on the plot (non-null y of the first series). */
  points(): number;
  update(x: Column, ys: Column[]): void;
  setPrediction(lines: PredLine[]): void;
  setMarker(t: number | null): void;
  setXRange(range: [number, number] | null): void;
  /** The alarms of what this plot shows (empty: none): redrawn with them. */
  setAlarms(marks: AlarmMark[]): void;
}

/** ``#rrggbb`` at opacity ``alpha``. */
function withAlpha(color: string, alpha: number): string {
  const m = /^#([0-9a-f]{2})([0-9a-f]{2})([0-9a-f]{2})$/i.exec(color);
  if (!m) return color;
  return `rgba(${parseInt(m[1], 16)}, ${parseInt(m[2], 16)}, ${parseInt(m[3], 16)}, ${alpha})`;
}

/** Shade an alarm's time in a band, and its threshold band, under the traces. */
function drawAlarmUnder(u: uPlot, mark: AlarmMark): void {
  const ctx = u.ctx;
  const { left, top, width, height } = u.bbox;
  const xs = u.data[0] as ArrayLike<number>;
  const lastX = xs.length ? xs[xs.length - 1] : (u.scales.x.max ?? 0);
  for (const span of mark.spans) {
    const a = u.valToPos(span.t0, "x", true);
    const b = u.valToPos(span.t1 ?? lastX, "x", true);
    const x0 = Math.max(left, Math.min(a, b));
    const x1 = Math.min(left + width, Math.max(a, b, a + 2 * devicePixelRatio));
    if (x1 <= x0) continue;
    ctx.fillStyle = withAlpha(span.color, 0.13);
    ctx.fillRect(x0, top, x1 - x0, height);
  }
  const band = mark.band;
  if (!band) return;
  ctx.strokeStyle = withAlpha(mark.color, 0.8);
  ctx.lineWidth = devicePixelRatio;
  ctx.setLineDash([3 * devicePixelRatio, 3 * devicePixelRatio]);
  if (band.kind === "levels") {
    for (const level of band.levels) {
      const y = u.valToPos(level.at, "y", true);
      const y0 = level.side === "above" ? top : y;
      const y1 = level.side === "above" ? y : top + height;
      const c0 = Math.max(top, y0);
      const c1 = Math.min(top + height, y1);
      if (c1 > c0) {
        ctx.fillStyle = withAlpha(mark.color, 0.12);
        ctx.fillRect(left, c0, width, c1 - c0);
      }
      if (y >= top && y <= top + height) {
        ctx.beginPath();
        ctx.moveTo(left, y);
        ctx.lineTo(left + width, y);
        ctx.stroke();
      }
    }
  } else {
    // ref ± halfWidth along the reference trace, broken where it is.
    const ys = u.data[band.ref + 1] as ArrayLike<number | null> | undefined;
    if (!ys) return;
    const step = Math.max(1, Math.floor(xs.length / (width / devicePixelRatio)));
    const runs: [number, number][][] = [];
    let run: [number, number][] = [];
    for (let k = 0; k < xs.length; k += step) {
      const y = ys[k];
      if (y === null || !Number.isFinite(y)) {
        if (run.length) runs.push(run);
        run = [];
      } else run.push([xs[k], y]);
    }
    if (run.length) runs.push(run);
    ctx.fillStyle = withAlpha(mark.color, 0.16);
    for (const r of runs) {
      const px = (x: number): number => u.valToPos(x, "x", true);
      const hi = r.map(([x, y]) => [px(x), u.valToPos(y + band.halfWidth, "y", true)]);
      const lo = r.map(([x, y]) => [px(x), u.valToPos(y - band.halfWidth, "y", true)]);
      ctx.beginPath();
      hi.forEach(([x, y], i) => (i ? ctx.lineTo(x, y) : ctx.moveTo(x, y)));
      for (let i = lo.length - 1; i >= 0; i--) ctx.lineTo(lo[i][0], lo[i][1]);
      ctx.closePath();
      ctx.fill();
      for (const edge of [hi, lo]) {
        ctx.beginPath();
        edge.forEach(([x, y], i) => (i ? ctx.lineTo(x, y) : ctx.moveTo(x, y)));
        ctx.stroke();
      }
    }
  }
  ctx.setLineDash([]);
}

/** The alarming series' trace again, thicker and in its band's colour, where it was in one. */
function drawAlarmOver(u: uPlot, mark: AlarmMark): void {
  if (mark.series === null) return;
  const xs = u.data[0] as ArrayLike<number>;
  const ys = u.data[mark.series + 1] as ArrayLike<number | null> | undefined;
  if (!ys || xs.length === 0) return;
  const ctx = u.ctx;
  ctx.lineWidth = 2.5 * devicePixelRatio;
  for (const span of mark.spans) {
    const t1 = span.t1 ?? Infinity;
    ctx.strokeStyle = span.color;
    ctx.beginPath();
    let pen = false;
    for (let k = 0; k < xs.length; k++) {
      const x = xs[k];
      if (x < span.t0) continue;
      if (x > t1) break;
      const y = ys[k];
      if (y === null || !Number.isFinite(y)) {
        pen = false;
        continue;
      }
      const px = u.valToPos(x, "x", true);
      const py = u.valToPos(y, "y", true);
      if (pen) ctx.lineTo(px, py);
      else ctx.moveTo(px, py);
      pen = true;
    }
    ctx.stroke();
  }
}

export function timePlot(
  parent: HTMLElement,
  title: string,
  unit: string,
  series: SeriesSpec[],
  height = 170,
  /** The least y span shown: sensor noise on a still joint must not fill the plot. */
  minSpan = 0,
): TimePlot {
  const el = document.createElement("div");
  el.className = "plot";
  parent.appendChild(el);
  let prediction: PredLine[] = [];
  let marker: number | null = null;
  let xRange: [number, number] | null = null;
  let pointCount = 0;
  let predMin = Infinity;
  let predMax = -Infinity;
  let alarms: AlarmMark[] = [];
  const tag = document.createElement("div");
  tag.className = "alarm-tag";
  tag.hidden = true;
  el.appendChild(tag);

  // Each alarm mark drawn by `draw`, clipped to the plotting area.
  const drawAlarms =
    (draw: (u: uPlot, mark: AlarmMark) => void) =>
    (u: uPlot): void => {
      if (alarms.length === 0) return;
      const { left, top, width, height: h } = u.bbox;
      u.ctx.save();
      u.ctx.beginPath();
      u.ctx.rect(left, top, width, h);
      u.ctx.clip();
      for (const mark of alarms) draw(u, mark);
      u.ctx.restore();
    };
  const drawAlarmsUnder = drawAlarms(drawAlarmUnder);
  const drawAlarmsOver = drawAlarms(drawAlarmOver);

  const drawPrediction = (u: uPlot): void => {
    if (prediction.length === 0) return;
    const ctx = u.ctx;
    const { left, top, width, height: h } = u.bbox;
    ctx.save();
    ctx.beginPath();
    ctx.rect(left, top, width, h);
    ctx.clip();
    ctx.strokeStyle = "rgba(200, 200, 200, 0.55)";
    ctx.lineWidth = 1.5 * devicePixelRatio;
    ctx.setLineDash([6 * devicePixelRatio, 4 * devicePixelRatio]);
    const [x0, x1] = [u.scales.x.min ?? -Infinity, u.scales.x.max ?? Infinity];
    for (const line of prediction) {
      ctx.beginPath();
      let started = false;
      // Thin the line to about one point per pixel: a 20-minute plan has ~5000 rows.
      const n = line.x.length;
      const step = Math.max(1, Math.floor(n / (width * 2)));
      for (let k = 0; k < n; k += step) {
        const xv = line.x[k];
        if (xv < x0 && k + step < n && line.x[k + step] < x0) continue;
        if (xv > x1 && started) break;
        const px = u.valToPos(xv, "x", true);
        const py = u.valToPos(line.y[k], "y", true);
        if (started) ctx.lineTo(px, py);
        else ctx.moveTo(px, py);
        started = true;
      }
      ctx.stroke();
    }
    ctx.restore();
  };

  const drawMarker = (u: uPlot): void => {
    if (marker === null) return;
    const px = u.valToPos(marker, "x", true);
    const { top, height: h } = u.bbox;
    const ctx = u.ctx;
    ctx.save();
    ctx.strokeStyle = "#e8b04a";
    ctx.lineWidth = devicePixelRatio;
    ctx.beginPath();
    ctx.moveTo(px, top);
    ctx.lineTo(px, top + h);
    ctx.stroke();
    ctx.restore();
  };

  const opts: uPlot.Options = {
    title: `${title} (${unit})`,
    width: Math.max(200, parent.clientWidth || 400),
    height,
    pxAlign: 0,
    legend: { live: false },
    cursor: { drag: { x: true, y: false } },
    scales: {
      x: {
        time: false,
        range: (_u, min, max) => (xRange ? xRange : [min, max]),
      },
      y: {
        // Hold the prediction as well as the data, so a plan line never leaves the plot.
        range: (_u, min, max) => {
          let lo = Math.min(min ?? Infinity, predMin);
          let hi = Math.max(max ?? -Infinity, predMax);
          if (!Number.isFinite(lo) || !Number.isFinite(hi)) return [-1, 1];
          const span = Math.max(minSpan, 1e-6);
          if (hi - lo < span) {
            const mid = (hi + lo) / 2;
            lo = mid - span / 2;
            hi = mid + span / 2;
          }
          const pad = 0.08 * (hi - lo);
          return [lo - pad, hi + pad];
        },
      },
    },
    axes: [
      { stroke: "#aab", grid: { stroke: "#2a2f3a" }, ticks: { stroke: "#2a2f3a" }, label: "plan time (s)" },
      { stroke: "#aab", grid: { stroke: "#2a2f3a" }, ticks: { stroke: "#2a2f3a" }, size: 55 },
    ],
    series: [
      {},
      ...series.map((s) => ({
        label: s.label,
        stroke: s.color,
        width: s.width ?? 1.5,
        dash: s.dash,
        spanGaps: false,
        points: { show: false },
      })),
    ],
    hooks: { drawAxes: [drawAlarmsUnder, drawPrediction], draw: [drawAlarmsOver, drawMarker] },
  };
  const empty: uPlot.AlignedData = [[], ...series.map(() => [])];
  const plot = new uPlot(opts, empty, el);
  const resize = new ResizeObserver(() => {
    const w = Math.max(200, el.clientWidth);
    if (Math.abs(w - plot.width) > 2) plot.setSize({ width: w, height });
  });
  resize.observe(el);

  return {
    plot,
    el,
    points: () => pointCount,
    update(x, ys) {
      let n = 0;
      const y0 = ys[0];
      for (let k = 0; k < y0.length; k++) if (y0[k] !== null) n++;
      pointCount = n;
      el.dataset.points = String(n);
      plot.setData([x, ...ys] as unknown as uPlot.AlignedData);
    },
    setPrediction(lines) {
      prediction = lines;
      predMin = Infinity;
      predMax = -Infinity;
      for (const line of lines) {
        for (let k = 0; k < line.y.length; k++) {
          const v = line.y[k];
          if (Number.isFinite(v)) {
            if (v < predMin) predMin = v;
            if (v > predMax) predMax = v;
          }
        }
      }
      plot.setData(plot.data, true);
    },
    setMarker(t) {
      marker = t;
      plot.redraw(false, false);
    },
    setXRange(range) {
      xRange = range;
      plot.setScale("x", { min: range?.[0] ?? 0, max: range?.[1] ?? 0 });
    },
    setAlarms(marks) {
      alarms = marks;
      const worst = marks[0] ?? null; // the caller orders them worst first
      el.classList.toggle("in-alarm", worst !== null);
      el.style.setProperty("--alarm", worst?.color ?? "transparent");
      el.dataset.alarmSeverity = worst?.severity ?? "";
      el.dataset.alarmChannels = marks.map((m) => m.channel).join(",");
      tag.hidden = worst === null;
      tag.textContent = marks.map((m) => m.label).join(" · ");
      tag.title = marks.map((m) => m.title).join("\n");
      tag.style.color = worst?.color ?? "";
      plot.redraw(false, false);
    },
  };
}

/** Pitch (deg) against pitch rate (deg/s): the flown trace, the plan's, and the latest point. */
export class PhasePlane {
  readonly canvas: HTMLCanvasElement;
  private flown: { x: Column; y: Column } = { x: [], y: [] };
  private planned: PredLine | null = null;
  private current: [number, number] | null = null;

  constructor(parent: HTMLElement) {
    const wrap = document.createElement("div");
    wrap.className = "phase";
    wrap.innerHTML = `<div class="phase-title">Pitch phase plane (deg vs deg/s)</div>`;
    this.canvas = document.createElement("canvas");
    wrap.appendChild(this.canvas);
    parent.appendChild(wrap);
    new ResizeObserver(() => this.draw()).observe(wrap);
  }

  set(pitchDeg: Column, rateDegps: Column, current: [number, number] | null): void {
    this.flown = { x: pitchDeg, y: rateDegps };
    this.current = current;
    this.draw();
  }

  setPlanned(line: PredLine | null): void {
    this.planned = line;
    this.draw();
  }

  draw(): void {
    const c = this.canvas;
    const w = c.clientWidth || 300;
    const h = c.clientHeight || 260;
    const dpr = devicePixelRatio;
    if (c.width !== Math.round(w * dpr) || c.height !== Math.round(h * dpr)) {
      c.width = Math.round(w * dpr);
      c.height = Math.round(h * dpr);
    }
    const ctx = c.getContext("2d");
    if (!ctx) return;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    ctx.clearRect(0, 0, w, h);
    // Symmetric ranges around 0 that hold every point (plan and flight).
    let xm = 1e-3;
    let ym = 1e-4;
    const scan = (xs: ArrayLike<number | null>, ys: ArrayLike<number | null>): void => {
      for (let k = 0; k < xs.length; k++) {
        const a = xs[k];
        const b = ys[k];
        if (a !== null && b !== null && Number.isFinite(a) && Number.isFinite(b)) {
          xm = Math.max(xm, Math.abs(a));
          ym = Math.max(ym, Math.abs(b));
        }
      }
    };
    scan(this.flown.x, this.flown.y);
    if (this.planned) scan(this.planned.x, this.planned.y);
    xm *= 1.1;
    ym *= 1.1;
    const pad = 34;
    const px = (v: number): number => pad + ((v + xm) / (2 * xm)) * (w - pad - 8);
    const py = (v: number): number => 8 + ((ym - v) / (2 * ym)) * (h - pad - 8);
    ctx.strokeStyle = "#2a2f3a";
    ctx.beginPath();
    ctx.moveTo(px(0), 8);
    ctx.lineTo(px(0), h - pad);
    ctx.moveTo(pad, py(0));
    ctx.lineTo(w - 8, py(0));
    ctx.stroke();
    ctx.fillStyle = "#aab";
    ctx.font = "11px sans-serif";
    ctx.fillText(`pitch ±${xm.toPrecision(2)} deg`, pad, h - 12);
    ctx.save();
    ctx.translate(12, h - pad);
    ctx.rotate(-Math.PI / 2);
    ctx.fillText(`rate ±${ym.toPrecision(2)} deg/s`, 0, 0);
    ctx.restore();
    const line = (xs: ArrayLike<number | null>, ys: ArrayLike<number | null>, style: string, dash: number[]): void => {
      ctx.strokeStyle = style;
      ctx.setLineDash(dash);
      ctx.beginPath();
      let pen = false;
      const step = Math.max(1, Math.floor(xs.length / 4000));
      for (let k = 0; k < xs.length; k += step) {
        const a = xs[k];
        const b = ys[k];
        if (a === null || b === null || !Number.isFinite(a) || !Number.isFinite(b)) {
          pen = false;
          continue;
        }
        if (pen) ctx.lineTo(px(a), py(b));
        else ctx.moveTo(px(a), py(b));
        pen = true;
      }
      ctx.stroke();
      ctx.setLineDash([]);
    };
    if (this.planned) line(this.planned.x, this.planned.y, "rgba(200,200,200,0.55)", [6, 4]);
    line(this.flown.x, this.flown.y, COLORS[0], []);
    if (this.current) {
      ctx.fillStyle = "#e8b04a";
      ctx.beginPath();
      ctx.arc(px(this.current[0]), py(this.current[1]), 4, 0, 2 * Math.PI);
      ctx.fill();
    }
  }
}
