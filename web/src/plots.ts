// Time plots (uPlot) with the plan's prediction drawn underneath as dashed grey lines, a
// marker for "now" or the replay time, and the pitch phase plane (a plain canvas).

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

export interface TimePlot {
  plot: uPlot;
  el: HTMLElement;
  /** Points on the plot (non-null y of the first series). */
  points(): number;
  update(x: Column, ys: Column[]): void;
  setPrediction(lines: PredLine[]): void;
  setMarker(t: number | null): void;
  setXRange(range: [number, number] | null): void;
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
    hooks: { drawAxes: [drawPrediction], draw: [drawMarker] },
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
