// REST client: the token from the sign-in, the server's one error shape (RFC 9457), and the
// feature probe (which optional endpoints this server offers, from its OpenAPI document).

import type { CommandStage, LinkStatus as LinkStatusDoc, ScheduleStatus } from "./protocol.gen";
import type { FlightRulesReport } from "./flightrules";
import { DEFAULT_JOINTS, jointCount, rawFields } from "./store";

export type Role = "viewer" | "operator";

export interface PassPublic {
  id: string;
  name: string;
  plan_id: string;
  aos_time: string;
  los_time: string;
  relay: string;
  state: string;
  state_reason: string | null;
  epoch_ns: number | null;
  created_at: string;
  updated_at: string;
  version: number;
  /** The computed contact window the pass was scheduled in (``aos_time`` and ``los_time``
   * are then its net time); null for a pass given by hand (absent: an older server). */
  window?: PassWindow | null;
}

/** A pass's computed window as it was computed when the pass was scheduled. */
export interface PassWindow {
  mission: string;
  mission_sha256: string;
  relay: string;
  aos_time: string;
  los_time: string;
  aos_margin_s: number;
  los_margin_s: number;
  net_s: number;
  min_range_km: number;
  max_range_km: number;
  light_time_min_s: number;
  light_time_max_s: number;
  processing_delay_s: number;
}

/** A contact window (``GET /api/windows``, docs/missions.md). */
export interface WindowPublic {
  relay: string;
  aos_time: string;
  los_time: string;
  duration_s: number;
  net_start_time: string;
  net_end_time: string;
  net_s: number;
  min_range_km: number;
  max_range_km: number;
  light_time_min_s: number;
  light_time_max_s: number;
}

export interface WindowsPublic {
  mission: string;
  mission_sha256: string;
  vehicle: string;
  start: string;
  hours: number;
  processing_delay_s: number;
  aos_margin_s: number;
  los_margin_s: number;
  data: WindowPublic[];
  count: number;
}

/** A mission the server computes windows for (``GET /api/missions``). */
export interface MissionPublic {
  name: string;
  description: string;
  vehicle: string;
  mission_sha256: string;
  epoch: string;
  /** The span ``GET /api/windows`` accepts: the elements' epoch -/+ the propagation's limit. */
  windows_from: string;
  windows_until: string;
  relays: { name: string; satellite: string; longitude_deg: number }[];
  station: string;
  processing_delay_s: number;
  aos_margin_s: number;
  los_margin_s: number;
}

export interface MissionsPublic {
  data: MissionPublic[];
  count: number;
  unloadable: { name: string; reason: string }[];
  max_hours: number;
}

export interface CommandPublic {
  seq: number;
  kind: string;
  execute_time_ns: number;
  payload: Record<string, unknown>;
  stage: CommandStage;
  reject_reason: string | null;
  /** Copies sent: the uplink retransmits until the vehicle acknowledges. */
  transmissions?: number;
  cancelled_at?: string | null;
}

export interface Segment {
  name: string;
  kind: string;
  t_start_s: number;
  t_end_s: number;
}

export interface PlanBrief {
  id: string;
  experiment: string;
  parameters: Record<string, unknown>;
  duration_s: number;
  n_commands: number;
  created_at: string;
}

export interface PlanPublic extends PlanBrief {
  metrics: Record<string, number>;
  segments: Segment[];
  /** The flight-rules report stored with the plan; null: never checked (absent: a server
   * from before the flight rules). */
  flight_rules?: FlightRulesReport | null;
}

export interface Prediction {
  t_s: number[];
  joints_rad: number[][];
  quat_orbit_from_base_xyzw: number[][];
  rpy_base_rad: number[][];
  omega_base_orbit_radps: number[][];
  wheel_momentum_nms: number[][];
}

export interface PlanDocument {
  experiment: string;
  /** The robot the plan is for (its description's name and hash); absent: ETS-VII. */
  robot?: string;
  robot_hash?: string;
  parameters: Record<string, unknown>;
  segments: Segment[];
  prediction: Prediction;
  metrics: Record<string, number>;
  /** The flight-rules report the plan carries (absent or null: never checked). */
  flight_rules?: FlightRulesReport | null;
}

/** A robot the server plans for (``GET /api/robots``). */
export interface RobotPose {
  name: string;
  description: string;
  joints_deg: number[] | null;
  hand_pos_robot_m: number[] | null;
  hand_rpy_deg: number[] | null;
}

export interface RobotPublic {
  name: string;
  description: string;
  n_joints: number;
  robot_hash: string;
  default: boolean;
  joint_limits_deg: number[][];
  poses: RobotPose[];
  experiments: Record<string, Record<string, unknown>>;
  /** Per experiment, the defaults a plan for this robot takes for the parameters a request
   * leaves out: ``experiments`` over what the tool derives for the robot (null: its own pose,
   * as when left out); absent from older servers. */
  experiment_defaults?: Record<string, Record<string, unknown>>;
  /** Per experiment, the keys of ``experiment_defaults`` the tool derived (not written in the
   * robot's description). */
  derived_defaults?: Record<string, string[]>;
  urdf_url: string;
}

/** The robot of a plan document, for the 3D view (absent fields: ETS-VII). */
export function planRobot(doc: PlanDocument): { name: string; hash: string | null } {
  return { name: doc.robot ?? "ets7", hash: doc.robot_hash ?? null };
}

export interface PlanValidation {
  valid: boolean;
  errors: { code: string; message: string }[];
  summary: (Omit<PlanPublic, "id" | "created_at">) | null;
  /** The rules table of a plan that plans (also when it fails a rule: then ``valid`` is
   * false with a ``flight_rule_violation`` error); null when it does not plan. */
  flight_rules?: FlightRulesReport | null;
}

/** The plan's flight-rules report: the server's answer's, else its document's. */
export function planRules(
  plan: { flight_rules?: FlightRulesReport | null } | null,
  doc: PlanDocument | null,
): FlightRulesReport | null {
  return plan?.flight_rules ?? doc?.flight_rules ?? null;
}

/** ``GET /api/link/status`` (the console's ``link`` message's ``status``, generated from
 * server/services/link.py, with the uplink's fields and the active pass). */
export interface LinkStatus extends Omit<LinkStatusDoc, "uplink"> {
  /** The running pass's uplink (server/services/uplink.py); null without one. */
  uplink: UplinkStatus | null;
  active_pass_id?: string | null;
}

export type { ScheduleStatus };

export interface UplinkStatus {
  pass_id: string;
  commands: number;
  sent: number;
  acknowledged: number;
  in_flight: number;
  expired: number;
  retransmissions: number;
  schedule_full_refusals: number;
  onboard_load: number | null;
  capacity: number;
  lead_window_s: number;
  rto_s: number;
  srtt_s: number | null;
  min_fill_margin_s: number | null;
}

export interface TelemetryPage {
  count: number;
  fields?: string[];
  truncated: boolean;
  rows: { seq: number; generation_time_ns: number; values: Record<string, unknown> }[] | null;
}

/** A refused request: the HTTP status and the server's error code and message. */
export class ApiError extends Error {
  constructor(
    readonly status: number,
    readonly code: string,
    message: string,
  ) {
    super(message);
  }
}

const TOKEN_KEY = "hikoboshi.token";

export function storedToken(): string | null {
  return sessionStorage.getItem(TOKEN_KEY);
}

export function storeToken(token: string | null): void {
  if (token === null) sessionStorage.removeItem(TOKEN_KEY);
  else sessionStorage.setItem(TOKEN_KEY, token);
}

export async function request<T>(method: string, path: string, body?: unknown): Promise<T> {
  const headers: Record<string, string> = {};
  const token = storedToken();
  if (token) headers.Authorization = `Bearer ${token}`;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const response = await fetch(path, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await response.text();
  let parsed: unknown = null;
  try {
    parsed = text ? JSON.parse(text) : null;
  } catch {
    parsed = null;
  }
  if (!response.ok) {
    // Problem details (RFC 9457): ``code`` and ``detail`` (the message).
    const problem = parsed as { code?: string; detail?: unknown } | null;
    throw new ApiError(
      response.status,
      problem?.code ?? `http_${response.status}`,
      typeof problem?.detail === "string"
        ? problem.detail
        : `${method} ${path}: HTTP ${response.status}`,
    );
  }
  return parsed as T;
}

export const get = <T>(path: string): Promise<T> => request<T>("GET", path);
export const post = <T>(path: string, body: unknown): Promise<T> => request<T>("POST", path, body);

/** Every page of a ``{data, count}`` listing. */
export async function getAll<T>(path: string, pageSize = 1000): Promise<T[]> {
  const out: T[] = [];
  const sep = path.includes("?") ? "&" : "?";
  for (;;) {
    const page = await get<{ data: T[]; count: number }>(
      `${path}${sep}offset=${out.length}&limit=${pageSize}`,
    );
    out.push(...page.data);
    if (page.data.length === 0 || out.length >= page.count) return out;
  }
}

let features: Promise<Set<string>> | null = null;

/** The API paths this server offers (its OpenAPI document): optional endpoints are used
 * when listed, and shown as not available otherwise, without probing them into 404s. */
export function apiPaths(): Promise<Set<string>> {
  if (features === null) {
    features = fetch("/openapi.json")
      .then((r) => (r.ok ? r.json() : { paths: {} }))
      .then((doc: { paths?: Record<string, unknown> }) => new Set(Object.keys(doc.paths ?? {})))
      .catch(() => new Set<string>());
  }
  return features;
}

/** The telemetry fields a store plots of a pass, for its robot's joints: the archive answers
 * a request without ``fields`` with the pass's own (``j1..jn``: its robot's), so an empty
 * range tells them without reading a frame. */
export async function passRawFields(passId: string): Promise<string[]> {
  const page = await get<TelemetryPage>(`/api/passes/${passId}/telemetry?t0=0&t1=1&limit=1`);
  return rawFields(jointCount(page.fields ?? []) || DEFAULT_JOINTS);
}
