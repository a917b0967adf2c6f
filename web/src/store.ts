// Telemetry of one pass, as plot-ready columns in display units (deg, deg/s, N m s) on the
// plan's time axis (s from the pass's epoch, onboard clock). Frames are identified by their
// seq (live and REST reloads merge without duplicates); a hole in the frames (more than
// GAP_S between two) gets a row of nulls, so the plots draw it as a gap, not a line.

//
// The joint count comes from the data (the ``j1..jn`` a message or a page names: the pass's
// robot's, telemetry/layout.py), not from a constant: ETS-VII has 6 until data says otherwise.

/** The most joints the archive stores (server/storage/models.py MAX_STORED_JOINTS). */
export const MAX_JOINTS = 12;
/** ETS-VII's joint count: a store's until its data names another. */
export const DEFAULT_JOINTS = 6;

/** The values a store keeps of a robot of ``n`` joints, in the order of a frame's ``v``:
 * measured joints, servo targets, base quaternion, base rates, wheel momentum. */
export function rawFields(n: number): string[] {
  const joints = Array.from({ length: n }, (_, i) => `j${i + 1}`);
  const targets = Array.from({ length: n }, (_, i) => `t${i + 1}`);
  return [...joints, ...targets, "qx", "qy", "qz", "qw", "wx", "wy", "wz", "hw1", "hw2", "hw3"];
}

/** Every joint up to the archive's most: what the console may ask of any pass (a pass's
 * robot's missing joints are left out of its messages). */
export const RAW_FIELDS: readonly string[] = rawFields(MAX_JOINTS);

/** The joint count of data that names ``j1..jn`` (0 when it names none). */
export function jointCount(names: Iterable<string>): number {
  let n = 0;
  for (const name of names) {
    const m = /^j([0-9]+)$/.exec(name);
    if (m) n = Math.max(n, Number(m[1]));
  }
  return n;
}

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
  n: number; // joints
  v: Float64Array; // rawFields(n)
}

/** A frame's measured joints (rad). */
export const frameJoints = (f: Frame): Float64Array => f.v.subarray(0, f.n);
/** A frame's servo targets (rad). */
export const frameTargets = (f: Frame): Float64Array => f.v.subarray(f.n, 2 * f.n);
/** A frame's quat_orbit_from_base (x, y, z, w). */
export const frameQuat = (f: Frame): Float64Array => f.v.subarray(2 * f.n, 2 * f.n + 4);
/** A frame's base rates, base frame (rad/s). */
export const frameRates = (f: Frame): Float64Array => f.v.subarray(2 * f.n + 4, 2 * f.n + 7);
/** A frame's wheel momentum, base frame (N m s). */
export const frameMomentum = (f: Frame): Float64Array => f.v.subarray(2 * f.n + 7, 2 * f.n + 10);

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
  /** The robot's joints: the data's (``j1..jn``), ETS-VII's until some came. */
  nJoints = DEFAULT_JOINTS;
  private frames: Frame[] = [];
  private seqs = new Set<number>();

  constructor(readonly epochNs: number) {
    this.reset();
  }

  private reset(): void {
    this.x = [];
    this.joints = Array.from({ length: this.nJoints }, () => []);
    this.targets = Array.from({ length: this.nJoints }, () => []);
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
    const n = this.nJoints;
    for (let i = 0; i < n; i++) {
      this.joints[i].push(v ? v[i] * DEG : null);
      this.targets[i].push(v ? v[n + i] * DEG : null);
    }
    if (v) {
      const q = 2 * n;
      const rpy = rpyFromQuat(v[q], v[q + 1], v[q + 2], v[q + 3]);
      for (let i = 0; i < 3; i++) {
        this.rpy[i].push(rpy[i] * DEG);
        this.rates[i].push(v[q + 4 + i] * DEG);
        this.momentum[i].push(v[q + 7 + i]);
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

  /** Take the joint count of incoming frames; frames held of another count (another
   * robot's: not expected within one pass) are dropped. True when it changed. */
  private takeJoints(n: number): boolean {
    if (n === this.nJoints) return false;
    this.nJoints = n;
    this.frames = this.frames.filter((f) => f.n === n);
    this.seqs = new Set(this.frames.map((f) => f.seq));
    return true;
  }

  private add(incoming: Frame[], live: boolean): void {
    let outOfOrder = false;
    let added = 0;
    if (incoming.length && this.takeJoints(incoming[0].n)) {
      this.count = this.frames.length;
      this.rebuild();
      this.version++;
    }
    for (const f of incoming) {
      if (this.seqs.has(f.seq) || f.n !== this.nJoints) continue;
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

  /** A console ``telemetry`` message's columns (its ``j1..jn`` give the joint count). */
  addColumns(columns: Record<string, unknown[]>, live = true): void {
    const seq = columns.seq as number[];
    const gen = columns.generation_time_ns as number[];
    const n = jointCount(Object.keys(columns)) || this.nJoints;
    const names = rawFields(n);
    const fields = names.map((name) => columns[name] as number[] | undefined);
    const frames: Frame[] = [];
    for (let k = 0; k < seq.length; k++) {
      const v = new Float64Array(names.length);
      for (let i = 0; i < fields.length; i++) v[i] = Number(fields[i]?.[k] ?? NaN);
      frames.push({ seq: seq[k], genNs: gen[k], n, v });
    }
    this.add(frames, live);
  }

  /** Raw rows of ``GET /api/passes/{id}/telemetry`` (their ``j1..jn`` give the joint count). */
  addRows(rows: { seq: number; generation_time_ns: number; values: Record<string, unknown> }[]): void {
    const n = (rows.length ? jointCount(Object.keys(rows[0].values)) : 0) || this.nJoints;
    const names = rawFields(n);
    const frames = rows.map((r) => {
      const v = new Float64Array(names.length);
      names.forEach((name, i) => (v[i] = Number(r.values[name] ?? NaN)));
      return { seq: r.seq, genNs: r.generation_time_ns, n, v };
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
