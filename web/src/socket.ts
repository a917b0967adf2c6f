// The console websocket (docs/console.md): auth as the first message, one subscription per
// stream, the dedupe rule (per stream: epoch and highest seq accepted), resume after a
// reconnect, resync (the caller reloads from REST), the server's word that this console is
// behind (``lag``), and a ping for the clock offset.

import type {
  AlarmMsg, EventMsg, LagMsg, LinkMsg, ReplayCommandsMsg, ReplayOpenedMsg, ReplayStateMsg, ReplayTelemetryMsg,
  ServerMessage, TelemetryMsg, WelcomeMsg,
} from "./protocol.gen";

/** The server's first message (generated from server/services/console_messages.py). */
export type Welcome = WelcomeMsg;

/** A message of a subscribed stream: ``telemetry``, ``link``, ``event`` or ``alarm``. */
export type Message = TelemetryMsg | LinkMsg | EventMsg | AlarmMsg;

/** A replay's data message (``topic: "replay"``). */
export type ReplayData = ReplayTelemetryMsg | ReplayCommandsMsg;

export interface SocketHandlers {
  welcome(w: Welcome): void;
  /** A message of a stream, after the dedupe rule. */
  message(m: Message): void;
  /** Nothing up to the stream's current seq will be replayed: reload it from REST (the
   * ``reason`` says why: a reconnect to another epoch, or ``behind by ...``). */
  resync(topic: string, passId: string | null, reason: string): void;
  /** How far behind the server measures this console (``behind_s`` 0: caught up). */
  lag(m: LagMsg): void;
  /** The token was refused (close 1008): sign out. */
  refused(reason: string): void;
  state(connected: boolean): void;
}

interface Stream {
  topic: string;
  passId: string | null;
  options: Record<string, unknown>;
  epoch: string | null;
  seq: number | null;
  /** Whether the first ``subscribed`` has come (before: the history is not loaded). */
  subscribed: boolean;
  onSubscribed?: () => void;
}

const key = (topic: string, passId: string | null): string => `${topic}|${passId ?? ""}`;

/** What a replay's owner hears (docs/console.md, "Replay of a recorded pass"). */
export interface ReplayHandlers {
  /** ``replay_opened``: also after a reconnect, when the replay was opened again. */
  opened(m: ReplayOpenedMsg): void;
  /** ``replay_state``. */
  state(m: ReplayStateMsg): void;
  /** A data message (``topic: "replay"``): ``telemetry`` or ``commands``. */
  data(m: ReplayData): void;
  /** An ``error`` answering one of this console's replay requests. */
  error(reason: string, refType: string): void;
  /** The socket dropped: the server closed the replay (it is opened again on reconnect). */
  lost(): void;
}

/** One replay opened by this console: requests go through it, replies come to its handlers. */
export class ReplayHandle {
  id: string | null = null;
  closed = false;

  constructor(
    private readonly socket: ConsoleSocket,
    readonly passId: string,
    readonly options: Record<string, unknown>,
    readonly handlers: ReplayHandlers,
  ) {}

  /** ``replay_play``, ``replay_pause``, ``replay_step``, ``replay_speed``, ``replay_seek``. */
  request(type: string, fields: Record<string, unknown> = {}): void {
    if (this.closed || this.id === null) return;
    this.socket.sendRaw({ type, replay_id: this.id, ...fields });
  }

  /** ``replay_close`` (now, or as soon as the pending open is answered). */
  close(): void {
    if (this.closed) return;
    this.closed = true;
    this.socket.forgetReplay(this);
  }
}

export class ConsoleSocket {
  private ws: WebSocket | null = null;
  private streams = new Map<string, Stream>();
  private epoch: string | null = null;
  private backoffMs = 250;
  private closed = false;
  private pingTimer: number | undefined;
  /** Messages read on this socket, and the count last acknowledged (``ack``, every 0.25 s):
   * the server then keeps what this console has not read in its own queues, where the
   * control messages jump the bulk data and a backlog can be dropped for a resync. */
  private received = 0;
  private acked = 0;
  private ackedAtMs = 0;
  private ackTimer: number | undefined;
  private pings = new Map<number, number>();
  private pingId = 0;
  /** Replays this console opened, by replay_id; and the opens awaiting their answer, in order. */
  private replays = new Map<string, ReplayHandle>();
  private replayOpens: ReplayHandle[] = [];
  private replayHandles = new Set<ReplayHandle>();
  /** Ground time minus browser time (ms), from the last pong. */
  clockOffsetMs = 0;
  /** The console socket's round trip (ms), from the last pong. */
  socketRttMs: number | null = null;
  connected = false;
  welcome: Welcome | null = null;
  /** The server's latest word on how far behind this console is (null: none yet). */
  lag: LagMsg | null = null;

  constructor(
    private readonly token: string,
    private readonly handlers: SocketHandlers,
  ) {
    this.open();
  }

  private open(): void {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    const ws = new WebSocket(`${scheme}://${location.host}/api/console`);
    this.ws = ws;
    this.received = 0;
    this.acked = 0;
    ws.onopen = () => ws.send(JSON.stringify({ v: 1, type: "auth", token: this.token }));
    ws.onmessage = (ev) => {
      // The server's messages are the generated types (tests/server/console hold them).
      if (typeof ev.data !== "string") return;
      this.received += 1;
      this.receive(JSON.parse(ev.data));
      // As it reads (timers are slowed in a background tab; messages are not), at most
      // every 0.25 s; the timer acknowledges the rest once messages stop.
      if (performance.now() - this.ackedAtMs >= 250) this.ack();
    };
    ws.onclose = (ev) => {
      this.ws = null;
      if (this.lag !== null && this.lag.behind_s > 0) {
        // A new connection starts with an empty queue: behind no longer.
        this.lag = { ...this.lag, behind_s: 0, queued: 0 };
        this.handlers.lag(this.lag);
      }
      this.setConnected(false);
      this.dropReplays();
      window.clearInterval(this.pingTimer);
      window.clearInterval(this.ackTimer);
      if (ev.code === 1008 && this.welcome === null) {
        this.closed = true;
        this.handlers.refused(ev.reason || "the token was refused");
        return;
      }
      if (this.closed) return;
      window.setTimeout(() => this.open(), this.backoffMs);
      this.backoffMs = Math.min(this.backoffMs * 2, 5000);
    };
  }

  close(): void {
    this.closed = true;
    window.clearInterval(this.pingTimer);
    window.clearInterval(this.ackTimer);
    this.ws?.close(1000, "console closed");
  }

  private setConnected(value: boolean): void {
    this.connected = value;
    this.handlers.state(value);
  }

  private send(message: Record<string, unknown>): void {
    if (this.ws?.readyState === WebSocket.OPEN) this.ws.send(JSON.stringify({ v: 1, ...message }));
  }

  /** Send a message as is (``v: 1`` added): the replay requests. */
  sendRaw(message: Record<string, unknown>): void {
    this.send(message);
  }

  /** Open a replay of a flown pass; ``options`` are replay_open's (``speed``, ``paused``,
   * ``fields``). Opened again (same options) after a reconnect, until closed. */
  openReplay(passId: string, options: Record<string, unknown>, handlers: ReplayHandlers): ReplayHandle {
    const handle = new ReplayHandle(this, passId, options, handlers);
    this.replayHandles.add(handle);
    if (this.welcome !== null && this.connected) this.sendReplayOpen(handle);
    return handle;
  }

  private sendReplayOpen(handle: ReplayHandle): void {
    this.replayOpens.push(handle);
    this.send({ type: "replay_open", pass_id: handle.passId, ...handle.options });
  }

  /** A handle closed: close its replay on the server (or when its open is answered). */
  forgetReplay(handle: ReplayHandle): void {
    this.replayHandles.delete(handle);
    if (handle.id !== null) {
      this.replays.delete(handle.id);
      this.send({ type: "replay_close", replay_id: handle.id });
    }
  }

  /** The socket dropped: the server ended every replay of this console. */
  private dropReplays(): void {
    const handles = [...this.replayHandles];
    this.replays.clear();
    this.replayOpens = [];
    for (const handle of handles) {
      handle.id = null;
      handle.handlers.lost();
    }
  }

  /** A replay's data: to its handle, if it is still open. */
  private replayData(m: ReplayData): void {
    const handle = this.replays.get(m.replay_id);
    if (handle && !handle.closed) handle.handlers.data(m);
  }

  /** An ``error`` answering a replay request: true when it was one. */
  private replayError(reason: string, refType: string | null): boolean {
    if (!refType?.startsWith("replay_")) return false;
    console.warn("console websocket (replay):", reason);
    if (refType === "replay_open") {
      const handle = this.replayOpens.shift();
      if (handle && !handle.closed) handle.handlers.error(reason, refType);
      return true;
    }
    for (const handle of this.replays.values()) handle.handlers.error(reason, refType);
    return true;
  }

  private replayOpened(m: ReplayOpenedMsg): void {
    const handle = this.replayOpens.shift();
    const id = m.replay_id;
    if (!handle || handle.closed) {
      // Its page went away before the answer: close it at once.
      this.send({ type: "replay_close", replay_id: id });
      return;
    }
    handle.id = id;
    this.replays.set(id, handle);
    handle.handlers.opened(m);
  }

  private sendSubscribe(s: Stream): void {
    const message: Record<string, unknown> = { type: "subscribe", topic: s.topic, ...s.options };
    if (s.passId !== null) message.pass_id = s.passId;
    if (s.seq !== null && s.epoch !== null) {
      message.since_seq = s.seq;
      message.epoch = s.epoch;
    }
    this.send(message);
  }

  /** Subscribe (or resume) a stream; ``onSubscribed`` runs once, at the first ``subscribed``. */
  subscribe(
    topic: string,
    passId: string | null,
    options: Record<string, unknown> = {},
    onSubscribed?: () => void,
  ): void {
    const k = key(topic, passId);
    const existing = this.streams.get(k);
    if (existing) {
      // Another page subscribed first: its stream serves this one too.
      if (!onSubscribed) return;
      if (existing.subscribed) queueMicrotask(onSubscribed);
      else {
        const previous = existing.onSubscribed;
        existing.onSubscribed = () => {
          previous?.();
          onSubscribed();
        };
      }
      return;
    }
    const s: Stream = { topic, passId, options, epoch: null, seq: null, subscribed: false, onSubscribed };
    this.streams.set(k, s);
    if (this.welcome !== null) this.sendSubscribe(s);
  }

  unsubscribe(topic: string, passId: string | null): void {
    if (!this.streams.delete(key(topic, passId))) return;
    const message: Record<string, unknown> = { type: "unsubscribe", topic };
    if (passId !== null) message.pass_id = passId;
    this.send(message);
  }

  /** Ground time now (ms since the Unix epoch), from the browser clock and the offset. */
  groundNowMs(): number {
    return Date.now() + this.clockOffsetMs;
  }

  private ack(): void {
    if (this.received === this.acked || this.welcome === null) return;
    this.acked = this.received;
    this.ackedAtMs = performance.now();
    this.send({ type: "ack", received: this.received });
  }

  private ping(): void {
    const id = ++this.pingId;
    this.pings.set(id, performance.now());
    this.send({ type: "ping", id });
  }

  private receive(m: ServerMessage): void {
    switch (m.type) {
      case "welcome": {
        this.backoffMs = 250;
        this.welcome = m;
        this.epoch = m.epoch;
        // Acknowledge from the start (before any data), then on a timer while messages come.
        this.send({ type: "ack", received: this.received });
        this.acked = this.received;
        window.clearInterval(this.ackTimer);
        this.ackTimer = window.setInterval(() => this.ack(), 250);
        this.setConnected(true);
        this.handlers.welcome(m);
        // Resume every stream: with the old seq and epoch (a new epoch answers resync).
        for (const s of this.streams.values()) this.sendSubscribe(s);
        for (const handle of this.replayHandles) this.sendReplayOpen(handle);
        this.ping();
        window.clearInterval(this.pingTimer);
        this.pingTimer = window.setInterval(() => this.ping(), 5000);
        return;
      }
      case "lag":
        this.lag = m;
        this.handlers.lag(m);
        return;
      case "pong": {
        if (typeof m.id !== "number") return;
        const sent = this.pings.get(m.id);
        this.pings.delete(m.id);
        if (sent === undefined) return;
        const now = performance.now();
        this.socketRttMs = now - sent;
        const groundMs = m.time_ns / 1e6;
        this.clockOffsetMs = groundMs + this.socketRttMs / 2 - Date.now();
        return;
      }
      case "subscribed": {
        const s = this.streams.get(key(m.topic, m.pass_id ?? null));
        if (!s) return;
        if (s.seq === null || s.epoch !== m.epoch) {
          // A fresh subscription: live messages follow ``seq``.
          if (s.seq === null) s.seq = m.seq;
          if (s.epoch === null) s.epoch = m.epoch;
        }
        if (!s.subscribed) {
          s.subscribed = true;
          s.onSubscribed?.();
        }
        return;
      }
      case "resync": {
        const passId = m.pass_id ?? null;
        const s = this.streams.get(key(m.topic, passId));
        if (!s) return;
        s.epoch = m.epoch;
        s.seq = m.seq;
        this.handlers.resync(s.topic, passId, m.reason);
        return;
      }
      case "unsubscribed": {
        const s = this.streams.get(key(m.topic, m.pass_id ?? null));
        if (s && m.reason !== "requested") this.sendSubscribe(s); // overflow: resume
        return;
      }
      case "error":
        if (!this.replayError(m.reason, m.ref_type)) console.warn("console websocket:", m.reason);
        return;
      case "replay_opened":
        this.replayOpened(m);
        return;
      case "replay_state": {
        const handle = this.replays.get(m.replay_id);
        if (handle && !handle.closed) handle.handlers.state(m);
        return;
      }
      case "replay_closed": {
        const handle = this.replays.get(m.replay_id);
        if (handle) {
          this.replays.delete(m.replay_id);
          handle.id = null;
        }
        return;
      }
      case "commands":
        this.replayData(m);
        return;
      case "telemetry":
        if (m.topic === "replay") this.replayData(m);
        else this.streamMessage(m);
        return;
      case "link":
      case "event":
      case "alarm":
        this.streamMessage(m);
        return;
    }
  }

  /** A message of a subscribed stream, after the dedupe rule. */
  private streamMessage(m: Message): void {
    const s = this.streams.get(key(m.topic, m.type === "telemetry" ? m.pass_id : null));
    if (!s) return;
    if (s.epoch !== null && s.epoch !== this.epoch) return; // the old epoch, awaiting resync
    if (s.seq !== null && m.seq <= s.seq) return; // the dedupe rule
    s.seq = m.seq;
    s.epoch = this.epoch;
    this.handlers.message(m);
  }
}
