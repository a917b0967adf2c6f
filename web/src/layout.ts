// The telemetry frame's columns for any robot, from the layout the server generated into
// protocol.gen.ts (telemetry/layout.py FrameLayout): nothing here names a column by hand.

import {
  DEFAULT_WHEELS, FRAME_LEADING, FRAME_SCALARS, FRAME_VECTORS, type FrameVector,
} from "./protocol.gen";

/** A vector's column names for a robot of ``nJoints`` joints and ``nWheels`` wheels. */
export function vectorColumns(array: FrameVector, nJoints: number, nWheels: number = DEFAULT_WHEELS): string[] {
  for (const v of FRAME_VECTORS) {
    if (v.array !== array) continue;
    if (v.columns !== null) return [...v.columns];
    const count = v.per === "joint" ? nJoints : nWheels;
    return Array.from({ length: count }, (_, i) => `${v.prefix}${i + 1}`);
  }
  throw new Error(`no frame vector ${array}`);
}

/** A row's columns, in order: ``FrameLayout(nJoints, nWheels).columns``. */
export function layoutColumns(nJoints: number, nWheels: number = DEFAULT_WHEELS): string[] {
  const vectors = FRAME_VECTORS.flatMap((v) => vectorColumns(v.array, nJoints, nWheels));
  return [...FRAME_LEADING, ...vectors, ...FRAME_SCALARS];
}
