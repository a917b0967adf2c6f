// Start and abort, for operators: each behind a confirmation that types the pass name.
// Viewers never get these buttons (and the server refuses them anyway: 403).

import { post, type PassPublic } from "../api";
import type { Ctx } from "../main";
import { confirmAction, h } from "../ui";

const STARTABLE = new Set(["scheduled"]);
const ABORTABLE = new Set(["scheduled", "aos", "running", "los"]);

/** The control buttons for ``pass`` (empty for a viewer); ``done`` runs after an action. */
export function passControls(ctx: Ctx, pass: PassPublic, done: () => void): HTMLElement {
  const box = h("span.controls");
  if (!ctx.canCommand) return box;
  if (STARTABLE.has(pass.state)) {
    const start = h("button.primary", { type: "button", "data-test": "start" }, "Start…");
    start.addEventListener("click", () =>
      confirmAction({
        action: "START",
        passName: pass.name,
        run: async () => {
          await post(`/api/passes/${pass.id}/start`, { confirm: `START ${pass.name}` });
          done();
        },
      }),
    );
    box.append(start);
  }
  if (ABORTABLE.has(pass.state)) {
    const abort = h("button.danger", { type: "button", "data-test": "abort" }, "Abort…");
    abort.addEventListener("click", () =>
      confirmAction({
        action: "ABORT",
        passName: pass.name,
        danger: true,
        reason: { label: "Reason (audit log)", value: "operator abort" },
        run: async (reason) => {
          await post(`/api/passes/${pass.id}/abort`, { confirm: `ABORT ${pass.name}`, reason });
          done();
        },
      }),
    );
    box.append(abort);
  }
  return box;
}
