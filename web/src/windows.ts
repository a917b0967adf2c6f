// Contact windows on the console (docs/console.md, "Timeline and countdown"): the clock the
// countdowns run on (the ground's UTC: the browser's clock corrected by the offset the
// console socket's pong measures, never the browser's clock alone once a pong has come), the
// countdown to a pass's window's loss of signal, and the next acquisition from the
// mission's computed windows (GET /api/missions, GET /api/windows).

import {
  ApiError, get,
  type MissionPublic, type MissionsPublic, type PassPublic, type WindowPublic, type WindowsPublic,
} from "./api";
import type { ConsoleSocket } from "./socket";
import { clock } from "./ui";

/** How far ahead the next acquisition is looked for (h of windows per request). */
export const NEXT_AOS_HOURS = 24;
/** At most one windows request per this long (wall ms) while none is known. */
const RETRY_MS = 30_000;

/** The console's UTC now: the ground's clock once the console socket has measured the
 * offset (``synced``), the browser's until then. */
export interface GroundNow {
  ms: number;
  synced: boolean;
}

export function groundNow(socket: ConsoleSocket): GroundNow {
  return { ms: socket.groundNowMs(), synced: socket.socketRttMs !== null };
}

/** A duration for a countdown: ``m:ss`` or ``h:mm:ss``, days beyond two days. */
export function span(seconds: number): string {
  const s = Math.abs(seconds);
  if (s < 48 * 3600) return clock(s);
  const days = Math.floor(s / 86400);
  return `${days} d ${clock(s - days * 86400)}`;
}

/** ``YYYY-MM-DD HH:MM:SSZ`` of ms since the epoch. */
export function utcText(ms: number): string {
  const text = new Date(ms).toISOString();
  return `${text.slice(0, 10)} ${text.slice(11, 19)}Z`;
}

export interface WindowCountdown {
  /** ``window``: the pass's computed window; ``hand``: a pass given by hand, no window. */
  kind: "window" | "hand";
  phase: "before" | "open" | "after";
  /** What it counts to: acquisition (before) or loss of signal. */
  target: "aos" | "los";
  targetMs: number;
  /** s from now to the target; negative once passed. */
  seconds: number;
  text: string;
}

/** The countdown of ``pass`` at ``nowMs``: to its window's AOS, then to its window's LOS
 * (with its net time's end, the pass's own ``los_time``); a pass given by hand says that
 * it has no window and counts to the times typed in. */
export function windowCountdown(pass: PassPublic, nowMs: number): WindowCountdown {
  const w = pass.window ?? null;
  const aosMs = Date.parse(w ? w.aos_time : pass.aos_time);
  const losMs = Date.parse(w ? w.los_time : pass.los_time);
  const netEndMs = Date.parse(pass.los_time);
  const phase = nowMs < aosMs ? "before" : nowMs < losMs ? "open" : "after";
  const target = phase === "before" ? "aos" : "los";
  const targetMs = target === "aos" ? aosMs : losMs;
  const seconds = (targetMs - nowMs) / 1000;
  let text: string;
  if (w === null) {
    const what = phase === "before" ? `typed AOS in ${span(seconds)}`
      : phase === "open" ? `typed LOS in ${span(seconds)}` : `typed LOS ${span(seconds)} ago`;
    text = `No computed window: a pass given by hand (AOS/LOS typed in) · ${what}`;
  } else if (phase === "before") {
    text = `${w.relay} AOS in ${span(seconds)}`;
  } else if (phase === "open") {
    const net = (netEndMs - nowMs) / 1000;
    text = `${w.relay} LOS in ${span(seconds)} · net time ${net > 0 ? `ends in ${span(net)}` : `ended ${span(net)} ago`}`;
  } else {
    text = `${w.relay} LOS ${span(seconds)} ago`;
  }
  return { kind: w === null ? "hand" : "window", phase, target, targetMs, seconds, text };
}

export type NextAos =
  | { kind: "window"; window: WindowPublic; aosMs: number; seconds: number; text: string }
  | { kind: "none"; text: string };

/** The first window of ``windows`` acquiring after ``nowMs`` (any relay), or null. */
export function firstAfter(windows: WindowPublic[], nowMs: number): WindowPublic | null {
  let best: WindowPublic | null = null;
  for (const w of windows) {
    const aos = Date.parse(w.aos_time);
    if (aos > nowMs && (best === null || aos < Date.parse(best.aos_time))) best = w;
  }
  return best;
}

/** The next acquisition of signal from a mission's computed windows, fetched as the clock
 * needs them (24 h from now at a time; again once they have all acquired). */
export class NextAcquisition {
  private mission: MissionPublic | null | undefined = undefined;
  private missionError: string | null = null;
  private windows: WindowPublic[] = [];
  private fetchedUntilMs = -Infinity;
  private loading = false;
  private lastTryMs = -Infinity;
  private error: string | null = null;
  private disposed = false;

  constructor(
    private readonly name: string | null,
    private readonly paths: Set<string>,
  ) {}

  dispose(): void {
    this.disposed = true;
  }

  at(nowMs: number): NextAos {
    const none = (text: string): NextAos => ({ kind: "none", text });
    if (this.name === null) return none("Next AOS: no mission to compute it from (a pass given by hand)");
    if (!this.paths.has("/api/missions") || !this.paths.has("/api/windows")) {
      return none("Next AOS: this server does not compute contact windows");
    }
    if (this.mission === undefined) {
      this.loadMission();
      return none(this.missionError ?? "Next AOS: loading the mission…");
    }
    if (this.mission === null) return none(`Next AOS: mission ${this.name} is not on this server`);
    const from = Date.parse(this.mission.windows_from);
    const until = Date.parse(this.mission.windows_until);
    if (nowMs < from || nowMs >= until) {
      return none(`Next AOS: not computed: ${this.name}'s elements reach ${utcText(from).slice(0, 10)} to `
        + `${utcText(until).slice(0, 10)}, and ground time is ${utcText(nowMs)}`);
    }
    const next = firstAfter(this.windows, nowMs);
    if (next !== null) {
      const aosMs = Date.parse(next.aos_time);
      const seconds = (aosMs - nowMs) / 1000;
      return { kind: "window", window: next, aosMs, seconds,
        text: `Next AOS: ${next.relay} in ${span(seconds)} (${utcText(aosMs)})` };
    }
    // None known after now: the fetched span has run out (or none was fetched yet).
    if (this.fetchedUntilMs - nowMs < 3600_000) this.load(nowMs, until);
    if (this.fetchedUntilMs > nowMs) {
      return none(`Next AOS: none before ${utcText(this.fetchedUntilMs)}`);
    }
    return none(this.error !== null ? `Next AOS: ${this.error}` : "Next AOS: computing the windows…");
  }

  private loadMission(): void {
    if (this.loading) return;
    this.loading = true;
    get<MissionsPublic>("/api/missions")
      .then((body) => {
        this.mission = body.data.find((m) => m.name === this.name) ?? null;
      })
      .catch((e: Error) => {
        this.missionError = `Next AOS: the missions did not load: ${e.message}`;
        window.setTimeout(() => (this.missionError = null), RETRY_MS);
      })
      .finally(() => (this.loading = false));
  }

  private load(nowMs: number, untilMs: number): void {
    if (this.loading || this.disposed || performance.now() - this.lastTryMs < RETRY_MS) return;
    this.loading = true;
    this.lastTryMs = performance.now();
    const startMs = Math.floor(nowMs / 60_000) * 60_000;
    const hours = Math.min(NEXT_AOS_HOURS, Math.floor((untilMs - startMs) / 60_000) / 60);
    if (hours <= 0) {
      this.loading = false;
      return;
    }
    const start = new Date(startMs).toISOString();
    get<WindowsPublic>(`/api/windows?mission=${encodeURIComponent(this.name ?? "")}&start=${encodeURIComponent(start)}&hours=${hours}`)
      .then((body) => {
        this.windows = body.data;
        this.fetchedUntilMs = startMs + hours * 3600_000;
        this.error = null;
      })
      .catch((e: Error) => {
        this.error = e instanceof ApiError ? `${e.message} (${e.code})` : e.message;
      })
      .finally(() => (this.loading = false));
  }
}
