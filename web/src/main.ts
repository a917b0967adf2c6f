// The console's shell: sign-in (token in sessionStorage), the role from the console
// websocket's welcome, navigation between the pages, the alarm banner over every page (the
// alarms and the link status it follows are the shell's, shared with the pages), and the
// socket's messages fanned out to whichever page is shown.

import "./style.css";
import { AlarmBook, type LinkWithMode } from "./alarms";
import { apiPaths, get, storedToken, storeToken, type Role } from "./api";
import { AlarmBanner } from "./banner";
import { alarmsPage } from "./pages/alarms";
import { livePage } from "./pages/live";
import { passesPage } from "./pages/passes";
import { planPage } from "./pages/plan";
import { reportPage } from "./pages/report";
import { timelinePage } from "./pages/timeline";
import type { LagMsg } from "./protocol.gen";
import { ConsoleSocket, type Message, type Welcome } from "./socket";
import { clear, h } from "./ui";

export interface Ctx {
  role: Role;
  actor: string;
  socket: ConsoleSocket;
  paths: Set<string>;
  /** Messages of every subscribed stream; returns the unsubscribe. */
  on(fn: (m: Message) => void): () => void;
  onResync(fn: (topic: string, passId: string | null, reason: string) => void): () => void;
  /** The server's word on how far behind this console is (``lag``). */
  onLag(fn: (m: LagMsg) => void): () => void;
  onSocketState(fn: (connected: boolean) => void): () => void;
  canCommand: boolean;
  /** The active alarms (every pass's), kept current from the ``alarms`` topic. */
  alarms: AlarmBook;
  /** The latest link status (REST, then the ``link`` topic); null before the first. */
  link: LinkWithMode | null;
}

export type Page = (root: HTMLElement, ctx: Ctx, params: string[]) => () => void;

const app = document.getElementById("app")!;

function listeners<A extends unknown[]>() {
  const set = new Set<(...args: A) => void>();
  return {
    add(fn: (...args: A) => void): () => void {
      set.add(fn);
      return () => set.delete(fn);
    },
    emit(...args: A): void {
      for (const fn of [...set]) fn(...args);
    },
  };
}

function signIn(message = ""): void {
  clear(app);
  const token = h("input", {
    type: "password",
    name: "token",
    autocomplete: "off",
    placeholder: "API token",
    "data-test": "token",
    required: true,
  });
  const error = h("p.error", { role: "alert", "data-test": "signin-error" }, message);
  const button = h("button.primary", { type: "submit", "data-test": "signin" }, "Sign in");
  const form = h(
    "form.signin",
    {},
    h("h1", {}, "Hikoboshi"),
    h("p.muted", {}, "ETS-VII ground station: operator console"),
    h("label", {}, "Token", token),
    error,
    button,
    h("p.muted.small", {}, "The token is kept in this tab only (sessionStorage)."),
  );
  form.addEventListener("submit", (ev) => {
    ev.preventDefault();
    button.disabled = true;
    error.textContent = "";
    start(token.value.trim(), (reason) => {
      button.disabled = false;
      error.textContent = `Sign-in refused: ${reason}`;
    });
  });
  app.appendChild(form);
  token.focus();
}

function start(token: string, refused: (reason: string) => void): void {
  const messages = listeners<[Message]>();
  const resyncs = listeners<[string, string | null, string]>();
  const lags = listeners<[LagMsg]>();
  const states = listeners<[boolean]>();
  let ctx: Ctx | null = null;
  const socket = new ConsoleSocket(token, {
    welcome(w: Welcome) {
      if (ctx === null) {
        storeToken(token);
        void apiPaths().then((paths) => {
          ctx = {
            role: w.role,
            actor: w.actor,
            socket,
            paths,
            on: messages.add,
            onResync: resyncs.add,
            onLag: lags.add,
            onSocketState: states.add,
            canCommand: w.role === "operator",
            alarms: new AlarmBook({ passId: null, activeOnly: true }),
            link: null,
          };
          shell(ctx);
        });
      }
    },
    message: (m) => messages.emit(m),
    resync: (topic, passId, reason) => resyncs.emit(topic, passId, reason),
    lag: (m) => lags.emit(m),
    refused(reason) {
      storeToken(null);
      if (ctx === null) refused(reason);
      else signIn(`Signed out: ${reason}`);
    },
    state: (connected) => states.emit(connected),
  });
}

const ROUTES: Record<string, Page> = {
  live: livePage,
  passes: passesPage,
  plan: planPage,
  report: reportPage,
  alarms: alarmsPage,
  timeline: timelinePage,
};

function shell(ctx: Ctx): void {
  clear(app);
  const status = h("span.socket", { "data-test": "socket-state", title: "console websocket" });
  const setStatus = (connected: boolean): void => {
    status.textContent = connected ? "● console connected" : "● console reconnecting…";
    status.classList.toggle("bad", !connected);
  };
  setStatus(ctx.socket.connected);
  ctx.onSocketState(setStatus);
  const behind = behindIndicator(ctx);
  const nav = h(
    "nav",
    {},
    h("a", { href: "#/live", "data-route": "live" }, "Live"),
    h("a", { href: "#/passes", "data-route": "passes" }, "Passes"),
    h("a", { href: "#/timeline", "data-route": "timeline" }, "Timeline"),
    h("a", { href: "#/plan", "data-route": "plan" }, "Planning"),
    h("a", { href: "#/alarms", "data-route": "alarms" }, "Alarms"),
  );
  const signOut = h("button.link", { type: "button", "data-test": "signout" }, "Sign out");
  signOut.addEventListener("click", () => {
    storeToken(null);
    ctx.socket.close();
    location.hash = "";
    signIn();
  });
  const header = h(
    "header",
    {},
    h("span.brand", {}, "HIKOBOSHI"),
    nav,
    h("span.spacer"),
    behind,
    status,
    h("span.who", { "data-test": "who" }, `${ctx.actor} · `, h(`b.role.${ctx.role}`, { "data-test": "role" }, ctx.role)),
    signOut,
  );
  const main = h("main");
  const banner = new AlarmBanner(ctx, ctx.alarms);
  app.append(h("div.topbar", {}, header, banner.el), main);
  followAlarmsAndLink(ctx, banner);
  let cleanup: (() => void) | null = null;
  const route = (): void => {
    const [name = "live", ...params] = location.hash.replace(/^#\/?/, "").split("/").filter(Boolean);
    const page = ROUTES[name] ?? livePage;
    for (const a of nav.querySelectorAll("a")) a.classList.toggle("active", a.dataset.route === name);
    cleanup?.();
    // a dialog belongs to the page it was opened on: leaving the page closes it
    for (const dialog of document.querySelectorAll("div.backdrop")) dialog.remove();
    clear(main);
    for (const k of Object.keys(main.dataset)) delete main.dataset[k];
    cleanup = page(main, ctx, params.map(decodeURIComponent));
  };
  window.addEventListener("hashchange", route);
  route();
}

/** How far behind the view is, as the server measures it (docs/console.md, "A console
 * behind"): shown while the server says so, and for at least 2 s, so that a resync (the
 * server dropped the backlog; the pages reload their snapshot) does not flicker by unseen. */
function behindIndicator(ctx: Ctx): HTMLElement {
  const el = h("span.behind", { "data-test": "behind", "data-value": "0", hidden: true, role: "status" });
  let shownAtMs = 0;
  let hideTimer: number | undefined;
  let resyncing = false;
  const show = (m: LagMsg): void => {
    window.clearTimeout(hideTimer);
    if (el.hidden) {
      shownAtMs = performance.now();
      resyncing = false;
    }
    el.hidden = false;
    el.dataset.value = String(m.behind_s);
    el.textContent = `⚠ view behind by ${m.behind_s.toFixed(1)} s${resyncing ? " · reloaded" : ""}`;
    el.title = `${m.queued} messages unsent by the server; past ${m.resync_s} s it drops them and the view reloads its snapshot`;
  };
  const caughtUp = (): void => {
    window.clearTimeout(hideTimer);
    el.dataset.value = "0";
    hideTimer = window.setTimeout(() => {
      el.hidden = true;
    }, Math.max(0, shownAtMs + 2000 - performance.now()));
  };
  ctx.onLag((m) => (m.behind_s > 0 ? show(m) : caughtUp()));
  ctx.onResync((_topic, _passId, reason) => {
    if (!reason.startsWith("behind by ") || el.hidden) return;
    resyncing = true;
    el.textContent = `⚠ view ${reason.replace(/: \d+ messages not sent; reload the snapshot$/, "")}: reloaded`;
  });
  if (ctx.socket.lag !== null && ctx.socket.lag.behind_s > 0) show(ctx.socket.lag);
  return el;
}

/** The shell's own streams: the alarms (the banner's counts, the pages' marks) and the link
 * status (the vehicle's mode): loaded from REST once subscribed, and again on a resync. */
function followAlarmsAndLink(ctx: Ctx, banner: AlarmBanner): void {
  const setLink = (status: LinkWithMode): void => {
    ctx.link = status;
    banner.setLink(status);
  };
  const loadLink = (): void => {
    get<LinkWithMode>("/api/link/status").then(setLink).catch(() => undefined);
  };
  ctx.on((m) => {
    if (m.type === "alarm") ctx.alarms.apply(m.alarm);
    else if (m.type === "link") setLink(m.status as LinkWithMode);
  });
  ctx.onResync((topic) => {
    if (topic === "alarms") void ctx.alarms.load();
    if (topic === "link") loadLink();
  });
  ctx.socket.subscribe("alarms", null, {}, () => void ctx.alarms.load());
  ctx.socket.subscribe("link", null, {}, loadLink);
}

const saved = storedToken();
if (saved) start(saved, (reason) => signIn(`Signed out: ${reason}`));
else signIn();
