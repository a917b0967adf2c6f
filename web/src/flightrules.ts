// The flight-rules report a plan carries (planner/flight_rules.py FlightRulesReport.to_dict):
// in the plan document under "flight_rules", and as `flight_rules` in the server's PlanPublic
// and PlanValidation answers. Written by hand from the report's documented shape
// (docs/robots.md, the planner's to_dict) until the server's pydantic model for it is in
// protocol.gen.ts; then this module re-exports the generated type.

/** The rules a report has a row for, in the planner's order. */
export type RuleName =
  | "clearance"
  | "self_clearance"
  | "attitude_excursion_feedback"
  | "attitude_excursion_free_drift"
  | "wheel_momentum"
  | "joint_limit_margin"
  | "hand_speed"
  | "fits_pass";

export type Vec3 = [number, number, number];

/** One rule evaluated on the plan's predicted motion. */
export interface RuleRow {
  rule: RuleName | string;
  /** The worst value over the plan (for clearance: the least distance, negative inside). */
  value: number;
  limit: number;
  unit: "m" | "deg" | "of limit" | "m/s" | "s" | string;
  /** "min": the value must stay at or above the limit; "max": at or below. */
  bound: "min" | "max";
  verdict: "pass" | "fail";
  /** Plan time (s) of the worst value; null for a rule without one (fits_pass). */
  t_s: number | null;
  /** Clearance rows only: the two bodies (URDF link names) of the worst pair. */
  bodies: [string, string] | null;
  /** Clearance rows only: each body's nearest point, in the robot frame (origin at joint 1,
   * the base's axes), in the order of ``bodies``. */
  points_robot_m: [Vec3, Vec3] | null;
  detail: string;
}

/** The least clearance over all pairs (both clearance rules') in each 4 Hz command period. */
export interface ClearanceTrace {
  t_s: number[];
  min_m: number[];
}

export interface FlightRulesReport {
  passed: boolean;
  robot: string;
  /** The fine grid's step (s) the motion was sampled at. */
  step_s: number;
  n_samples: number;
  n_pairs: number;
  n_queries: number;
  rows: RuleRow[];
  clearance: ClearanceTrace;
}

/** The rows of pairs of bodies: "clearance" (the arm against the base and its equipment)
 * and "self_clearance" (arm links against each other). */
export const CLEARANCE_RULES: ReadonlySet<string> = new Set(["clearance", "self_clearance"]);

/** The clearance row that matters most (null without one): the least distance among the
 * failing clearance rows, else among all of them. */
export function clearanceRow(report: FlightRulesReport | null | undefined): RuleRow | null {
  const rows = (report?.rows ?? []).filter((r) => CLEARANCE_RULES.has(r.rule));
  const failing = rows.filter((r) => r.verdict === "fail");
  const pool = failing.length ? failing : rows;
  return pool.reduce<RuleRow | null>((best, r) => (best === null || r.value < best.value ? r : best), null);
}

/** The worst pair of bodies, when the clearance row names one with its nearest points and
 * its time: what the 3D view highlights. */
export interface WorstPair {
  /** The clearance rule whose worst pair it is. */
  rule: string;
  t_s: number;
  bodies: [string, string];
  points_robot_m: [Vec3, Vec3];
  distance_m: number;
  limit_m: number;
  failed: boolean;
}

export function worstPair(report: FlightRulesReport | null | undefined): WorstPair | null {
  const row = clearanceRow(report);
  if (!row || row.t_s === null || !row.bodies || !row.points_robot_m) return null;
  return {
    rule: row.rule,
    t_s: row.t_s,
    bodies: row.bodies,
    points_robot_m: row.points_robot_m,
    distance_m: row.value,
    limit_m: row.limit,
    failed: row.verdict === "fail",
  };
}
