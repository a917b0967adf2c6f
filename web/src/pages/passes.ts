// Every pass, newest AOS last, with its state (an aborted or safed pass with its reason)
// and the ways into it: live view, report, and (operators) start and abort.

import { getAll, type PassPublic } from "../api";
import type { Ctx } from "../main";
import { clear, h, utc } from "../ui";
import { passControls, stateBadge, stateReason } from "./control";

export function passesPage(root: HTMLElement, ctx: Ctx): () => void {
  const table = h("table.list", { "data-test": "passes" });
  const note = h("p.muted");
  root.append(h("h1", {}, "Passes"), note, table);
  let reload: number | undefined;
  const load = (): void => {
    getAll<PassPublic>("/api/passes")
      .then((passes) => {
        clear(table);
        note.textContent = passes.length ? "" : "No passes yet: schedule one in Planning.";
        table.append(h("tr", {}, ...["Name", "State", "AOS", "LOS", "Relay", ""].map((t) => h("th", {}, t))));
        for (const p of [...passes].reverse()) {
          table.append(
            h("tr", { "data-pass": p.id, "data-name": p.name },
              h("td", {}, h("a", { href: `#/live/${p.id}` }, p.name)),
              h("td", {}, stateBadge(p, "pass-state"), stateReason(p)),
              h("td", {}, utc(p.aos_time)),
              h("td", {}, utc(p.los_time)),
              h("td", {}, p.relay),
              h("td", {}, h("a", { href: `#/live/${p.id}` }, "Live"), " · ", h("a", { href: `#/report/${p.id}` }, "Report"), " ",
                passControls(ctx, p, load))));
        }
      })
      .catch((e: Error) => {
        note.textContent = e.message;
        note.className = "error";
      });
  };
  const off = ctx.on((m) => {
    if (m.topic === "passes") {
      window.clearTimeout(reload);
      reload = window.setTimeout(load, 200);
    }
  });
  ctx.socket.subscribe("passes", null);
  load();
  return () => {
    off();
    window.clearTimeout(reload);
  };
}
