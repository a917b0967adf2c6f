// The console websocket (docs/console.md): auth as the first message, one subscription per
// stream, the dedupe rule (per stream: epoch and highest seq accepted), resume after a
// reconnect, resync (the caller reloads from REST), and a ping for the clock offset.

import type { Role } from "./api";

export interface Welcome {
  epoch: string;
  actor: string;
  role: Role;
  topics: string[];
}

export type Message = Record<string, unknown> & { type: string; topic?: string; seq?: number };

export interface SocketHandlers {
  welcome(w: Welcome): void;
  /** A message of a stream, after the dedupe rule. */
  message(m: Message): void;
  /** Nothing up to the stream's current seq will be replayed: reload it from REST. */
  resync(topic: string, passId: string | null): void;
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

export class ConsoleSocket {
  private ws: WebSocket | null = null;
  private streams = new Map<string, Stream>();
  private epoch: string | null = null;
  private backoffMs = 250;
  private closed = false;
  private pingTimer: number | undefined;
  private pings = new Map<number, number>();
  private pingId = 0;
  /** Ground time minus browser time (ms), from the last pong. */
  clockOffsetMs = 0;
  /** The console socket's round trip (ms), from the last pong. */
  socketRttMs: number | null = null;
  connected = false;
  welcome: Welcome | null = null;

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
    ws.onopen = () => ws.send(JSON.stringify({ v: 1, type: "auth", token: this.token }));
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") this.receive(JSON.parse(ev.data) as Message);
    };
    ws.onclose = (ev) => {
      this.ws = null;
      this.setConnected(false);
      window.clearInterval(this.pingTimer);
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
    this.ws?.close(1000, "console closed");
  }

  private setConnected(value: boolean): void {
    this.connected = value;
    this.handlers.state(value);
  }

  private send(message: Record<string, unknown>): void {
    if (this.ws?.readyState === WebSocket.OPEN) this.ws.send(JSON.stringify({ v: 1, ...message }));
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

  private ping(): void {
    const id = ++this.pingId;
    this.pings.set(id, performance.now());
    this.send({ type: "ping", id });
  }

  private receive(m: Message): void {
    switch (m.type) {
      case "welcome": {
        this.backoffMs = 250;
        this.welcome = m as unknown as Welcome;
        this.epoch = this.welcome.epoch;
        this.setConnected(true);
        this.handlers.welcome(this.welcome);
        // Resume every stream: with the old seq and epoch (a new epoch answers resync).
        for (const s of this.streams.values()) this.sendSubscribe(s);
        this.ping();
        window.clearInterval(this.pingTimer);
        this.pingTimer = window.setInterval(() => this.ping(), 5000);
        return;
      }
      case "pong": {
        const sent = this.pings.get(m.id as number);
        this.pings.delete(m.id as number);
        if (sent === undefined) return;
        const now = performance.now();
        this.socketRttMs = now - sent;
        const groundMs = (m.time_ns as number) / 1e6;
        this.clockOffsetMs = groundMs + this.socketRttMs / 2 - Date.now();
        return;
      }
      case "subscribed": {
        const s = this.streams.get(key(m.topic as string, (m.pass_id as string) ?? null));
        if (!s) return;
        if (s.seq === null || s.epoch !== (m.epoch as string)) {
          // A fresh subscription: live messages follow ``seq``.
          if (s.seq === null) s.seq = m.seq as number;
          if (s.epoch === null) s.epoch = m.epoch as string;
        }
        if (!s.subscribed) {
          s.subscribed = true;
          s.onSubscribed?.();
        }
        return;
      }
      case "resync": {
        const passId = (m.pass_id as string) ?? null;
        const s = this.streams.get(key(m.topic as string, passId));
        if (!s) return;
        s.epoch = m.epoch as string;
        s.seq = m.seq as number;
        this.handlers.resync(s.topic, passId);
        return;
      }
      case "unsubscribed": {
        const s = this.streams.get(key(m.topic as string, (m.pass_id as string) ?? null));
        if (s && m.reason !== "requested") this.sendSubscribe(s); // overflow: resume
        return;
      }
      case "error":
        console.warn("console websocket:", m.reason);
        return;
      default: {
        if (typeof m.seq !== "number" || typeof m.topic !== "string") return;
        const s = this.streams.get(key(m.topic, (m.pass_id as string) ?? null));
        if (!s) return;
        if (s.epoch !== null && s.epoch !== this.epoch) return; // the old epoch, awaiting resync
        if (s.seq !== null && m.seq <= s.seq) return; // the dedupe rule
        s.seq = m.seq;
        s.epoch = this.epoch;
        this.handlers.message(m);
      }
    }
  }
}
