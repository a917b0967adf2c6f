// Start and abort, for operators: each behind a confirmation that types the pass name;
// and leaving the vehicle's SAFE mode (the safe-exit telecommand), behind the vehicle's name.
// Viewers never get these buttons (and the server refuses them anyway: 403). A refusal
// (the vehicle is safe, not safe, not connected, the name mistyped) shows in the dialog with
// the server's reason.

import { post, type PassPublic } from "../api";
import type { Ctx } from "../main";
import { confirmAction, h } from "../ui";

const STARTABLE = new Set(["scheduled"]);
const ABORTABLE = new Set(["scheduled", "aos", "running", "los"]);
/** The states that end a pass early: their reason is shown beside them. */
const REASONED = new Set(["aborted", "safed"]);

/** A pass's state as a badge (its reason in the tooltip). */
export function stateBadge(pass: PassPublic, test?: string): HTMLElement {
  const attrs: Record<string, string> = { title: pass.state_reason ?? "", "data-state": pass.state };
  if (test) attrs["data-test"] = test;
  return h(`span.badge.state-${pass.state}`, attrs, pass.state.toUpperCase());
}

/** Why a pass ended where it did (shown for the states that end a pass early). */
export function stateReason(pass: PassPublic): HTMLElement | null {
  if (!REASONED.has(pass.state) || !pass.state_reason) return null;
  return h("span.state-reason", { "data-test": "state-reason" }, pass.state_reason);
}

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

/** Leave SAFE (operators, while the vehicle is safe): ``POST /api/vehicle/safe-exit`` with
 * ``EXIT SAFE <vehicle>`` typed; ``done`` runs once the ground has sent it. */
export function safeExitButton(ctx: Ctx, vehicle: string, done: () => void = () => undefined): HTMLElement | null {
  if (!ctx.canCommand) return null;
  const button = h("button.danger", { type: "button", "data-test": "safe-exit" }, "Exit SAFE…");
  button.addEventListener("click", () =>
    confirmAction({
      action: "EXIT SAFE",
      passName: vehicle,
      noun: "vehicle",
      danger: true,
      run: async () => {
        await post("/api/vehicle/safe-exit", { confirm: `EXIT SAFE ${vehicle}` });
        done();
      },
    }),
  );
  return button;
}
