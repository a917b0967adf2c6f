// The console's shell: sign-in (token in sessionStorage), the role from the console
// websocket's welcome, navigation between the pages, and the socket's messages fanned out
// to whichever page is shown.

import "./style.css";
import { apiPaths, storedToken, storeToken, type Role } from "./api";
import { livePage } from "./pages/live";
import { passesPage } from "./pages/passes";
import { planPage } from "./pages/plan";
import { reportPage } from "./pages/report";
import { ConsoleSocket, type Message, type Welcome } from "./socket";
import { clear, h } from "./ui";

export interface Ctx {
  role: Role;
  actor: string;
  socket: ConsoleSocket;
  paths: Set<string>;
  /** Messages of every subscribed stream; returns the unsubscribe. */
  on(fn: (m: Message) => void): () => void;
  onResync(fn: (topic: string, passId: string | null) => void): () => void;
  onSocketState(fn: (connected: boolean) => void): () => void;
  canCommand: boolean;
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
  const resyncs = listeners<[string, string | null]>();
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
            onSocketState: states.add,
            canCommand: w.role === "operator",
          };
          shell(ctx);
        });
      }
    },
    message: (m) => messages.emit(m),
    resync: (topic, passId) => resyncs.emit(topic, passId),
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
  const nav = h(
    "nav",
    {},
    h("a", { href: "#/live", "data-route": "live" }, "Live"),
    h("a", { href: "#/passes", "data-route": "passes" }, "Passes"),
    h("a", { href: "#/plan", "data-route": "plan" }, "Planning"),
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
    status,
    h("span.who", { "data-test": "who" }, `${ctx.actor} · `, h(`b.role.${ctx.role}`, { "data-test": "role" }, ctx.role)),
    signOut,
  );
  const main = h("main");
  app.append(header, main);
  let cleanup: (() => void) | null = null;
  const route = (): void => {
    const [name = "live", ...params] = location.hash.replace(/^#\/?/, "").split("/").filter(Boolean);
    const page = ROUTES[name] ?? livePage;
    for (const a of nav.querySelectorAll("a")) a.classList.toggle("active", a.dataset.route === name);
    cleanup?.();
    clear(main);
    for (const k of Object.keys(main.dataset)) delete main.dataset[k];
    cleanup = page(main, ctx, params.map(decodeURIComponent));
  };
  window.addEventListener("hashchange", route);
  route();
}

const saved = storedToken();
if (saved) start(saved, (reason) => signIn(`Signed out: ${reason}`));
else signIn();
