// The plots of a pass, shared by the live view, the plan preview and the report: joints
// (measured, servo target, plan), base attitude, base rates, wheel momentum, the pitch
// phase plane and the 3D view. Fed by a TelemetryStore (flown) and a plan document
// (prediction, drawn dashed underneath). Above them, the plan's flight rules (table and
// clearance plot); the 3D view shows their worst pair of bodies at its worst moment. The
// pass's alarms mark the plot of what they watch (setAlarms).

import {
  SEVERITY_COLORS, SEVERITY_RANK, alarmLimit, alarmSpans, alarmSubject, alarmValue, type Alarm,
} from "../alarms";
import type { PlanDocument } from "../api";
import { worstPair, type FlightRulesReport, type WorstPair } from "../flightrules";
import { fetchUrdf, SatelliteView, type RobotRef } from "../model3d";
import { COLORS, PhasePlane, timePlot, type AlarmMark, type PredLine, type TimePlot } from "../plots";
import {
  DEFAULT_JOINTS, frameJoints, frameQuat, frameRates, frameTargets, rpyFromQuat,
  type Column, type Frame, type TelemetryStore,
} from "../store";
import { clear, h } from "../ui";
import { RulesPanel } from "./rules";

const DEG = 180 / Math.PI;
const AXES = ["x", "y", "z"];

export interface PredictionColumns {
  t: number[];
  joints: number[][]; // deg, per joint
  rpy: number[][]; // deg
  rates: number[][]; // deg/s, base frame
  momentum: number[][]; // N m s
  quat: number[][]; // rows, x y z w
  jointsRad: number[][]; // rows
}

/** The plan's prediction in display units; rates turned from the orbit frame to the base
 * frame (the gyro's), omega_base = R^T omega_orbit with R = rot_orbit_from_base. */
export function predictionColumns(doc: PlanDocument): PredictionColumns {
  const p = doc.prediction;
  const n = p.t_s.length;
  const nJoints = p.joints_rad[0]?.length ?? DEFAULT_JOINTS; // the robot's
  const out: PredictionColumns = {
    t: p.t_s,
    joints: Array.from({ length: nJoints }, (_, i) => p.joints_rad.map((r) => r[i] * DEG)),
    rpy: [[], [], []],
    rates: [[], [], []],
    momentum: Array.from({ length: 3 }, (_, i) => p.wheel_momentum_nms.map((r) => r[i])),
    quat: p.quat_orbit_from_base_xyzw,
    jointsRad: p.joints_rad,
  };
  for (let k = 0; k < n; k++) {
    const [x, y, z, w] = p.quat_orbit_from_base_xyzw[k];
    const rpy = rpyFromQuat(x, y, z, w);
    const o = p.omega_base_orbit_radps[k];
    // Columns of R: R^T o = (col0 . o, col1 . o, col2 . o).
    const c0 = [1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w)];
    const c1 = [2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w)];
    const c2 = [2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)];
    const ob = [c0, c1, c2].map((c) => c[0] * o[0] + c[1] * o[1] + c[2] * o[2]);
    for (let i = 0; i < 3; i++) {
      out.rpy[i].push(rpy[i] * DEG);
      out.rates[i].push(ob[i] * DEG);
    }
  }
  return out;
}

export class PassView {
  readonly el: HTMLElement;
  readonly joints: TimePlot[] = [];
  readonly attitude: TimePlot;
  readonly rates: TimePlot;
  readonly momentum: TimePlot;
  readonly phase: PhasePlane;
  view3d: SatelliteView | null = null;
  readonly rules: RulesPanel;
  /** What the rules panel's "worst moment" button does (the page may move its scrub too);
   * by default the 3D view shows the worst moment. */
  onShowWorst: (t: number) => void = () => this.showWorstMoment();
  private pred: PredictionColumns | null = null;
  private worst: WorstPair | null = null;
  /** Half the rules' sampling step: a pose this near the worst moment is shown with the pair. */
  private worstTolS = 0;
  /** The 3D view shows the predicted pose at the worst moment (with the pair highlighted). */
  private atWorst = false;
  private readonly jointGrid: HTMLElement;
  private readonly bodyPlots: TimePlot[];
  private readonly holder: HTMLElement;
  private readonly paths: Set<string>;
  private robotKey: string | null = null;
  private disposed = false;
  private alarms: Alarm[] = [];
  private alarmEpochNs: number | null = null;
  private alarmKey = "";

  /** The 3D view waits for :meth:`setRobot` (the plan's robot). */
  constructor(parent: HTMLElement, paths: Set<string>) {
    this.el = h("section.passview");
    parent.appendChild(this.el);
    const jointGrid = h("div.grid.joints", { "data-test": "joint-plots" });
    this.jointGrid = jointGrid;
    const bodyGrid = h("div.grid.body");
    const side = h("div.side");
    const caption = h("p.caption.muted.small", {},
      "Solid: flown (telemetry). Thin dashed: commanded servo target. Grey dashed: the plan's prediction. Amber line: now / replay time. Breaks in a line: missing frames.");
    const rulesHolder = h("div.rules-holder");
    this.el.append(h("div.plots", {}, rulesHolder, caption, jointGrid, bodyGrid), side);
    this.rules = new RulesPanel(rulesHolder, (t) => this.onShowWorst(t));
    this.setJointCount(DEFAULT_JOINTS);
    const three = (color: string[]) => AXES.map((a, i) => ({ label: a, color: color[i] }));
    this.attitude = timePlot(bodyGrid, "Base attitude roll / pitch / yaw", "deg", [
      { label: "roll", color: COLORS[0] },
      { label: "pitch", color: COLORS[1] },
      { label: "yaw", color: COLORS[2] },
    ], 170, 0.05);
    this.rates = timePlot(bodyGrid, "Base rates (base frame)", "deg/s", three(COLORS.slice(3)), 170, 0.01);
    this.momentum = timePlot(bodyGrid, "Wheel momentum", "N m s", three([COLORS[0], COLORS[1], COLORS[2]]), 170, 0.1);
    this.bodyPlots = [this.attitude, this.rates, this.momentum];
    this.attitude.el.dataset.test = "plot-attitude";
    this.rates.el.dataset.test = "plot-rates";
    this.momentum.el.dataset.test = "plot-momentum";
    this.phase = new PhasePlane(side);
    this.holder = h("div.view3d-holder", { "data-test": "view3d-holder" },
      h("div.phase-title", {}, "Satellite and arm (solid: measured, ghost: commanded)"));
    side.appendChild(this.holder);
    this.paths = paths;
  }

  /** Draw ``robot`` in 3D: the robot of the plan (its document's ``robot`` and
   * ``robot_hash``), from its own URDF; null when the plan is unknown (nothing is drawn:
   * never another robot's model). Again with the same robot: nothing to do. */
  setRobot(robot: RobotRef | null): void {
    const key = robot ? `${robot.name ?? ""}/${robot.hash ?? ""}` : "";
    if (this.robotKey === key) return;
    this.robotKey = key;
    const holder = this.holder;
    this.view3d?.dispose();
    this.view3d = null;
    for (const el of [...holder.querySelectorAll(".view3d, p.unavailable")]) el.remove();
    if (robot === null) {
      holder.append(h("p.unavailable", {}, "3D model not available: the pass's plan did not load."));
      return;
    }
    holder.dataset.robot = robot.name ?? "";
    void fetchUrdf(this.paths, robot).then(({ urdf, reason }) => {
      if (this.robotKey !== key || this.disposed) return;
      const view = new SatelliteView(holder);
      if (urdf === null || !view.load(urdf)) {
        view.dispose();
        view.el.remove();
        holder.append(h("p.unavailable", { "data-test": "view3d-unavailable" },
          `3D model not available: ${urdf === null ? reason : "its URDF does not parse"}.`));
        return;
      }
      this.view3d = view;
      const initial = this.pred;
      if (this.atWorst) this.showWorstMoment();
      else if (initial) view.setPose(initial.jointsRad[0], null, initial.quat[0]);
    });
  }

  private get plots(): TimePlot[] {
    return [...this.joints, ...this.bodyPlots];
  }

  /** One plot per joint of the robot (its data's count; ETS-VII's 6 until data came). */
  setJointCount(n: number): void {
    if (n === this.joints.length) return;
    for (const p of this.joints.splice(0)) p.plot.destroy();
    clear(this.jointGrid);
    for (let i = 0; i < n; i++) {
      const color = COLORS[i % COLORS.length];
      this.joints.push(
        timePlot(this.jointGrid, `Joint ${i + 1}`, "deg", [
          { label: "measured", color },
          { label: "commanded", color, dash: [4, 3], width: 1 },
        ], 150, 1.0),
      );
    }
    const pred = this.pred;
    this.joints.forEach((p, i) => p.setPrediction(pred?.joints[i] ? [{ x: pred.t, y: pred.joints[i] }] : []));
    if (this.bodyPlots) {
      // (not while constructing: the other plots come after the joints')
      this.alarmKey = "";
      this.markAlarms();
    }
  }

  /** The pass's alarms (``epochNs``: its plan clock's zero, onboard): each marks the plot of
   * what it watches, worst first: its time in a band shaded and the trace coloured there, its
   * threshold as a band where the plot shows it (a joint's tracking error around the
   * commanded trace, the body rate's and the clearance's levels), a tag naming it. */
  setAlarms(alarms: Alarm[], epochNs: number | null): void {
    this.alarms = alarms;
    this.alarmEpochNs = epochNs;
    this.markAlarms();
  }

  private markAlarms(): void {
    const key = JSON.stringify([this.alarmEpochNs, this.joints.length, this.alarms.map((a) => [a.id, a.updated_time_ns])]);
    if (key === this.alarmKey) return;
    this.alarmKey = key;
    const marks = new Map<TimePlot, AlarmMark[]>();
    for (const p of [...this.plots, this.rules.plot]) marks.set(p, []);
    const rank = (a: Alarm): number => SEVERITY_RANK[a.current_severity ?? a.severity];
    for (const a of [...this.alarms].sort((x, y) => rank(y) - rank(x))) {
      const target = this.alarmTarget(a);
      if (!target) continue;
      const spans = this.alarmEpochNs === null ? [] : alarmSpans(a, this.alarmEpochNs);
      marks.get(target.plot)!.push({
        series: target.series,
        color: SEVERITY_COLORS[a.current_severity ?? a.severity],
        severity: a.current_severity ?? a.severity,
        channel: a.channel,
        label: `${(a.current_severity ?? a.severity).toUpperCase()} ${a.channel || a.quantity}`
          + `${a.state === "cleared" ? " (cleared)" : ""}: ${alarmValue(a.worst_value, a.unit)} ${alarmLimit(a)}`,
        title: `${a.severity} alarm: ${alarmSubject(a)}, worst ${alarmValue(a.worst_value, a.unit)}, last `
          + `${alarmValue(a.last_value, a.unit)}, limit ${alarmLimit(a)}, ${a.state}`
          + `${a.acknowledged ? `, acknowledged by ${a.acknowledged_by ?? "?"}` : ", not acknowledged"}`,
        spans: spans.map((s) => ({ t0: s.t0, t1: s.t1, color: SEVERITY_COLORS[s.severity] })),
        band: target.band,
      });
    }
    for (const [plot, list] of marks) plot.setAlarms(list);
  }

  /** The plot (and series) that shows what alarm ``a`` watches; null when none does (the
   * link's health, the schedule's occupancy: the live view's panels show those). */
  private alarmTarget(a: Alarm): { plot: TimePlot; series: number | null; band?: AlarmMark["band"] } | null {
    const index = (prefix: string): number => {
      const m = new RegExp(`^${prefix}([0-9]+)$`).exec(a.channel);
      return m ? Number(m[1]) - 1 : -1;
    };
    const limit = a.limit;
    switch (a.quantity) {
      case "joint_tracking_error_deg":
      case "joint_limit_distance_deg": {
        const plot = this.joints[index("joint")];
        if (!plot) return null;
        // The tracking error is the commanded target less the measured angle: the band
        // around the commanded trace is where the measured one stays within the limit.
        const band = a.quantity === "joint_tracking_error_deg" && limit !== null
          ? { kind: "around" as const, ref: 1, halfWidth: limit } : undefined;
        return { plot, series: 0, band };
      }
      case "attitude_error_deg": {
        const axis = AXES.indexOf(a.channel);
        return axis < 0 ? { plot: this.attitude, series: null } : { plot: this.attitude, series: axis };
      }
      case "body_rate_degps":
        return {
          plot: this.rates, series: null,
          band: limit === null ? undefined : { kind: "levels", levels: [{ at: limit, side: "above" }, { at: -limit, side: "below" }] },
        };
      case "wheel_momentum_fraction":
      case "wheel_speed_rpm": {
        const wheel = index("wheel");
        return { plot: this.momentum, series: wheel >= 0 && wheel < 3 ? wheel : null };
      }
      case "clearance_m":
        return {
          plot: this.rules.plot, series: 0,
          band: limit === null ? undefined : { kind: "levels", levels: [{ at: limit, side: "below" }] },
        };
      default:
        return null;
    }
  }

  setPrediction(pred: PredictionColumns | null): void {
    this.pred = pred;
    if (pred) this.setJointCount(pred.joints.length);
    const lines = (cols: number[][]): PredLine[] => (pred ? cols.map((y) => ({ x: pred.t, y })) : []);
    this.joints.forEach((p, i) => p.setPrediction(pred?.joints[i] ? [{ x: pred.t, y: pred.joints[i] }] : []));
    this.attitude.setPrediction(lines(pred?.rpy ?? []));
    this.rates.setPrediction(lines(pred?.rates ?? []));
    this.momentum.setPrediction(lines(pred?.momentum ?? []));
    this.phase.setPlanned(pred ? { x: pred.rpy[1], y: pred.rates[1] } : null);
  }

  /** Offer to check plan ``planId`` when it has no report (the rules panel's button);
   * ``done`` is given the report the ground stored. */
  offerRulesCheck(planId: string, done: (report: FlightRulesReport) => void): void {
    this.rules.offerCheck(planId, (report) => {
      this.setFlightRules(report);
      done(report);
    });
  }

  /** The plan's flight-rules report (null: never checked): the table, the clearance plot,
   * and the worst pair the 3D view highlights at its moment. */
  setFlightRules(report: FlightRulesReport | null): void {
    this.rules.set(report);
    this.worst = worstPair(report);
    this.worstTolS = report ? Math.max(1e-6, report.step_s / 2) : 0;
    if (this.atWorst) this.showWorstMoment();
  }

  /** The 3D view at the worst clearance's moment: the arm in its predicted pose then, the
   * pair highlighted. False (nothing changed) without a worst pair or a prediction. */
  showWorstMoment(): boolean {
    const worst = this.worst;
    if (!worst || !this.pred || this.pred.t.length === 0) return false;
    this.atWorst = true;
    this.showPredictedAt(worst.t_s);
    return true;
  }

  /** Whether the plan fails its clearance rule (its worst pair then deserves the 3D view). */
  get clearanceFails(): boolean {
    return this.worst?.failed ?? false;
  }

  /** The worst pair's plan time (s); null without one. */
  get worstTime(): number | null {
    return this.worst?.t_s ?? null;
  }

  /** Plot what ``store`` holds. */
  showStore(store: TelemetryStore): void {
    this.setJointCount(store.nJoints);
    this.joints.forEach((p, i) => p.update(store.x, [store.joints[i], store.targets[i]]));
    this.attitude.update(store.x, store.rpy);
    this.rates.update(store.x, store.rates);
    this.momentum.update(store.x, store.momentum);
    const last = store.latest;
    this.phase.set(store.rpy[1], store.rates[1], last ? this.pitchPoint(last) : null);
    if (last) this.showFrame(last);
  }

  /** Plot the prediction as the data (the plan preview, before anything flies). */
  showPredictionAsData(pred: PredictionColumns): void {
    const none: Column = pred.t.map(() => null);
    this.setJointCount(pred.joints.length);
    this.joints.forEach((p, i) => p.update(pred.t, [pred.joints[i], none]));
    this.attitude.update(pred.t, pred.rpy);
    this.rates.update(pred.t, pred.rates);
    this.momentum.update(pred.t, pred.momentum);
  }

  private pitchPoint(f: Frame): [number, number] {
    const [x, y, z, w] = frameQuat(f);
    const rpy = rpyFromQuat(x, y, z, w);
    return [rpy[1] * DEG, frameRates(f)[1] * DEG];
  }

  /** The 3D pose and phase-plane point of one frame (flown: no worst pair shown). */
  showFrame(f: Frame): void {
    this.setWorstShown(false);
    this.view3d?.setPose(frameJoints(f), frameTargets(f), frameQuat(f));
  }

  /** The predicted pose at plan time ``t`` (preview): joints linear between the prediction's
   * samples; the worst pair highlighted when ``t`` is its moment. */
  showPredictedAt(t: number): void {
    const pred = this.pred;
    if (!pred || pred.t.length === 0) return;
    const { joints, k } = predictedJointsAt(pred, t);
    const worst = this.worst;
    this.view3d?.setPose(joints, null, pred.quat[k]);
    this.setWorstShown(worst !== null && Math.abs(t - worst.t_s) <= this.worstTolS);
    this.phase.set([], [], [pred.rpy[1][k], pred.rates[1][k]]);
  }

  private setWorstShown(on: boolean): void {
    if (!on && !this.atWorst) return; // nothing highlighted (a new view starts without)
    this.atWorst = on;
    this.view3d?.showWorstPair(on ? this.worst : null);
  }

  setMarker(t: number | null): void {
    for (const p of this.plots) p.setMarker(t);
    this.rules.setMarker(t);
  }

  setXRange(range: [number, number] | null): void {
    for (const p of this.plots) p.setXRange(range);
    this.rules.setXRange(range);
  }

  /** Points on each plot (the tests and the bench read these). */
  pointCounts(): number[] {
    return this.plots.map((p) => p.points());
  }

  dispose(): void {
    this.disposed = true;
    this.view3d?.dispose();
    for (const p of this.plots) p.plot.destroy();
    this.rules.dispose();
  }
}

/** The predicted joints (rad) at plan time ``t``, linear between the two samples around it
 * (held before the first and after the last), and the index of the sample nearest ``t``. */
export function predictedJointsAt(pred: PredictionColumns, t: number): { joints: number[]; k: number } {
  const ts = pred.t;
  const n = ts.length;
  let lo = 0;
  let hi = n - 1;
  if (t <= ts[0]) return { joints: [...pred.jointsRad[0]], k: 0 };
  if (t >= ts[hi]) return { joints: [...pred.jointsRad[hi]], k: hi };
  while (hi - lo > 1) {
    const mid = (lo + hi) >> 1;
    if (ts[mid] <= t) lo = mid;
    else hi = mid;
  }
  const f = (t - ts[lo]) / (ts[hi] - ts[lo] || 1);
  const a = pred.jointsRad[lo];
  const b = pred.jointsRad[hi];
  return { joints: a.map((v, i) => v + f * (b[i] - v)), k: f < 0.5 ? lo : hi };
}
