// Telemetry of one pass, as plot-ready columns in display units (deg, deg/s, N m s) on the
// plan's time axis (s from the pass's epoch, onboard clock). Frames are identified by their
// seq (live and REST reloads merge without duplicates); a hole in the frames (more than
// GAP_S between two) gets a row of nulls, so the plots draw it as a gap, not a line.

//
// The joint count comes from the data (the ``j1..jn`` a message or a page names: the pass's
// robot's, telemetry/layout.py), not from a constant: ETS-VII has 6 until data says otherwise.
// The values kept and their order come from the layout (protocol.gen.ts, generated from
// telemetry/layout.py): a frame's ``v`` is the columns of STORE_VECTORS.

import { vectorColumns } from "./layout";
import {
  DEFAULT_JOINTS, MAX_STORED_JOINTS, type FrameColumns, type FrameVector,
} from "./protocol.gen";

/** The most joints the archive stores (server/storage/models.py MAX_STORED_JOINTS). */
export const MAX_JOINTS = MAX_STORED_JOINTS;
/** ETS-VII's joint count: a store's until its data names another. */
export { DEFAULT_JOINTS };

/** The vectors a store keeps of a frame, in the order of its ``v``: measured joints, servo
 * targets, base quaternion, base rates, wheel momentum. */
const STORE_VECTORS = [
  "joints_rad",
  "joint_targets_rad",
  "quat_orbit_from_base_xyzw",
  "omega_base_in_base_radps",
  "wheel_momentum_nms",
] as const satisfies readonly FrameVector[];

/** The values a store keeps of a robot of ``n`` joints, in the order of a frame's ``v``. */
export function rawFields(n: number): string[] {
  return STORE_VECTORS.flatMap((array) => vectorColumns(array, n));
}

type StoreVector = (typeof STORE_VECTORS)[number];

/** Where each kept vector starts and ends in a frame's ``v`` of a robot of ``n`` joints. */
function slices(n: number): Map<StoreVector, [number, number]> {
  let at = 0;
  const out = new Map<StoreVector, [number, number]>();
  for (const array of STORE_VECTORS) {
    const width = vectorColumns(array, n).length;
    out.set(array, [at, at + width]);
    at += width;
  }
  return out;
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

const SLICES = new Map<number, Map<StoreVector, [number, number]>>();
/** A frame's values of one kept vector. */
function frameVector(f: Frame, array: StoreVector): Float64Array {
  let s = SLICES.get(f.n);
  if (s === undefined) SLICES.set(f.n, (s = slices(f.n)));
  const [lo, hi] = s.get(array)!;
  return f.v.subarray(lo, hi);
}

/** A frame's measured joints (rad). */
export const frameJoints = (f: Frame): Float64Array => frameVector(f, "joints_rad");
/** A frame's servo targets (rad). */
export const frameTargets = (f: Frame): Float64Array => frameVector(f, "joint_targets_rad");
/** A frame's quat_orbit_from_base (x, y, z, w). */
export const frameQuat = (f: Frame): Float64Array => frameVector(f, "quat_orbit_from_base_xyzw");
/** A frame's base rates, base frame (rad/s). */
export const frameRates = (f: Frame): Float64Array => frameVector(f, "omega_base_in_base_radps");
/** A frame's wheel momentum, base frame (N m s). */
export const frameMomentum = (f: Frame): Float64Array => frameVector(f, "wheel_momentum_nms");

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
    const n = this.nJoints;
    const joints = f ? frameJoints(f) : null;
    const targets = f ? frameTargets(f) : null;
    for (let i = 0; i < n; i++) {
      this.joints[i].push(joints ? joints[i] * DEG : null);
      this.targets[i].push(targets ? targets[i] * DEG : null);
    }
    if (f) {
      const [qx, qy, qz, qw] = frameQuat(f);
      const rates = frameRates(f);
      const momentum = frameMomentum(f);
      const rpy = rpyFromQuat(qx, qy, qz, qw);
      for (let i = 0; i < 3; i++) {
        this.rpy[i].push(rpy[i] * DEG);
        this.rates[i].push(rates[i] * DEG);
        this.momentum[i].push(momentum[i]);
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
  addColumns(columns: FrameColumns, live = true): void {
    const seq = columns.seq;
    const gen = columns.generation_time_ns;
    const n = jointCount(Object.keys(columns)) || this.nJoints;
    const names = rawFields(n);
    const fields = names.map((name) => columns[name]);
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
