// Telemetry of one pass, as plot-ready columns in display units (deg, deg/s, N m s) on the
// plan's time axis (s from the pass's epoch, onboard clock). Frames are identified by their
// seq (live and REST reloads merge without duplicates); a hole in the frames (more than
// GAP_S between two) gets a row of nulls, so the plots draw it as a gap, not a line.

export const RAW_FIELDS = [
  "j1", "j2", "j3", "j4", "j5", "j6",
  "t1", "t2", "t3", "t4", "t5", "t6",
  "qx", "qy", "qz", "qw",
  "wx", "wy", "wz",
  "hw1", "hw2", "hw3",
] as const;

/** A frame farther than this (onboard s) from the previous one starts a new line. */
export const GAP_S = 1.0;

const DEG = 180 / Math.PI;

export type Column = (number | null)[];

/** ``(roll, pitch, yaw)`` in rad of ``Rz(yaw) Ry(pitch) Rx(roll)`` (planner/frames.py). */
export function rpyFromQuat(x: number, y: number, z: number, w: number): [number, number, number] {
  const r00 = 1 - 2 * (y * y + z * z);
  const r10 = 2 * (x * y + z * w);
  const r20 = 2 * (x * z - y * w);
  const r21 = 2 * (y * z + x * w);
  const r22 = 1 - 2 * (x * x + y * y);
  const pitch = Math.atan2(-r20, Math.hypot(r00, r10));
  return [Math.atan2(r21, r22), pitch, Math.atan2(r10, r00)];
}

interface Frame {
  seq: number;
  genNs: number;
  v: Float64Array; // RAW_FIELDS
}

export class TelemetryStore {
  x: Column = [];
  joints: Column[] = [];
  targets: Column[] = [];
  rpy: Column[] = [];
  rates: Column[] = [];
  momentum: Column[] = [];
  /** Distinct frames held. */
  count = 0;
  /** Bumped on every change: plots redraw when it moved. */
  version = 0;
  /** ``performance.now()`` when the last new frame came. */
  lastFrameMs: number | null = null;
  latest: Frame | null = null;
  private frames: Frame[] = [];
  private seqs = new Set<number>();

  constructor(readonly epochNs: number) {
    this.reset();
  }

  private reset(): void {
    this.x = [];
    this.joints = Array.from({ length: 6 }, () => []);
    this.targets = Array.from({ length: 6 }, () => []);
    this.rpy = Array.from({ length: 3 }, () => []);
    this.rates = Array.from({ length: 3 }, () => []);
    this.momentum = Array.from({ length: 3 }, () => []);
  }

  /** Plan time (s) of an onboard time. */
  t(genNs: number): number {
    return (genNs - this.epochNs) / 1e9;
  }

  private pushRow(f: Frame | null, x: number): void {
    this.x.push(x);
    const v = f?.v;
    for (let i = 0; i < 6; i++) {
      this.joints[i].push(v ? v[i] * DEG : null);
      this.targets[i].push(v ? v[6 + i] * DEG : null);
    }
    if (v) {
      const rpy = rpyFromQuat(v[12], v[13], v[14], v[15]);
      for (let i = 0; i < 3; i++) {
        this.rpy[i].push(rpy[i] * DEG);
        this.rates[i].push(v[16 + i] * DEG);
        this.momentum[i].push(v[19 + i]);
      }
    } else {
      for (let i = 0; i < 3; i++) {
        this.rpy[i].push(null);
        this.rates[i].push(null);
        this.momentum[i].push(null);
      }
    }
  }

  private append(f: Frame): void {
    const last = this.latest;
    if (last !== null && (f.genNs - last.genNs) / 1e9 > GAP_S) {
      this.pushRow(null, this.t((f.genNs + last.genNs) / 2));
    }
    this.pushRow(f, this.t(f.genNs));
    this.latest = f;
  }

  private rebuild(): void {
    this.frames.sort((a, b) => a.genNs - b.genNs);
    this.reset();
    this.latest = null;
    for (const f of this.frames) this.append(f);
  }

  private add(incoming: Frame[], live: boolean): void {
    let outOfOrder = false;
    let added = 0;
    for (const f of incoming) {
      if (this.seqs.has(f.seq)) continue;
      this.seqs.add(f.seq);
      this.frames.push(f);
      added++;
      if (!outOfOrder && (this.latest === null || f.genNs > this.latest.genNs)) this.append(f);
      else outOfOrder = true;
    }
    if (added === 0) return;
    if (outOfOrder) this.rebuild();
    this.count = this.frames.length;
    if (live) this.lastFrameMs = performance.now();
    this.version++;
  }

  /** A console ``telemetry`` message's columns. */
  addColumns(columns: Record<string, unknown[]>, live = true): void {
    const seq = columns.seq as number[];
    const gen = columns.generation_time_ns as number[];
    const fields = RAW_FIELDS.map((name) => columns[name] as number[] | undefined);
    const frames: Frame[] = [];
    for (let k = 0; k < seq.length; k++) {
      const v = new Float64Array(RAW_FIELDS.length);
      for (let i = 0; i < fields.length; i++) v[i] = Number(fields[i]?.[k] ?? NaN);
      frames.push({ seq: seq[k], genNs: gen[k], v });
    }
    this.add(frames, live);
  }

  /** Raw rows of ``GET /api/passes/{id}/telemetry``. */
  addRows(rows: { seq: number; generation_time_ns: number; values: Record<string, unknown> }[]): void {
    const frames = rows.map((r) => {
      const v = new Float64Array(RAW_FIELDS.length);
      RAW_FIELDS.forEach((name, i) => (v[i] = Number(r.values[name] ?? NaN)));
      return { seq: r.seq, genNs: r.generation_time_ns, v };
    });
    this.add(frames, false);
  }

  /** Frames already held by another store (copied as they are). */
  addFrames(frames: Frame[]): void {
    this.add(frames, false);
  }

  /** The frames before onboard time ``ns``, in time order. */
  framesBefore(ns: number): Frame[] {
    const out: Frame[] = [];
    for (const f of this.frames) if (f.genNs < ns) out.push(f);
    return out.sort((a, b) => a.genNs - b.genNs);
  }

  /** The frame at or just before plan time ``t`` (replay), or null. */
  frameAt(t: number): Frame | null {
    const ns = this.epochNs + t * 1e9;
    let lo = 0;
    let hi = this.frames.length - 1;
    if (hi < 0 || this.frames[0].genNs > ns) return null;
    while (lo < hi) {
      const mid = (lo + hi + 1) >> 1;
      if (this.frames[mid].genNs <= ns) lo = mid;
      else hi = mid - 1;
    }
    return this.frames[lo];
  }

  get first(): Frame | null {
    return this.frames.length ? this.frames[0] : null;
  }
}

export type { Frame };
