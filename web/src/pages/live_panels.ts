// The live view's command panels (pages/live.ts): the onboard schedule and uplink gauges
// from the link status, and the commands' stage counts, their strip on the pass's time axis
// (a tick per command at its tag, coloured by stage; "now" in amber) and the next and
// latest commands.

import type { CommandPublic, LinkStatus, PassPublic, PlanDocument } from "../api";
import { COMMAND_STAGES, FINAL_STAGES, type CommandStage } from "../protocol.gen";
import { clear, fmt, h } from "../ui";

export interface CommandPanel {
  stageCounts: HTMLElement;
  cancelNote: HTMLElement;
  timeline: HTMLCanvasElement;
  nextList: HTMLElement;
}

const STAGE_COLORS: Record<CommandStage, string> = {
  queued: "#5a6272",
  released: "#7e8aa3",
  sent: "#4f8df7",
  received: "#4fc3f7",
  executed: "#81c784",
  rejected: "#e57373",
  expired: "#ffb74d",
  cancelled: "#ba68c8",
};
/** The strip's mark under a command sent more than once. */
const RESENT_COLOR = "#e6e9ef";

export function renderSchedule(scheduleBox: HTMLElement, s: LinkStatus | null, pass: PassPublic): void {
  clear(scheduleBox);
  scheduleBox.classList.toggle("is-stale", !s?.connected);
  const sched = s?.schedule ?? null;
  const up = s?.uplink && s.uplink.pass_id === pass.id ? s.uplink : null;
  if (!sched && !up) {
    scheduleBox.append(h("p.muted", {}, "No schedule report yet."));
    return;
  }
  const windowS = up?.lead_window_s ?? null;
  const gauge = (text: string, pct: number, test: string, value: number | null) =>
    h("div.gauge", {},
      h("div.bar", { style: `width:${Math.max(0, Math.min(100, pct)).toFixed(1)}%` }),
      h("span.gtext", { "data-test": test, "data-value": value ?? "" }, text));
  if (sched) {
    const through = sched.last_tag_ns !== null && pass.epoch_ns !== null
      ? `t = ${fmt((sched.last_tag_ns - pass.epoch_ns) / 1e9, 1)} s` : null;
    const lead = sched.lead_s;
    scheduleBox.append(
      gauge(`schedule: ${sched.queued}/${sched.capacity} queued`, (100 * sched.queued) / sched.capacity,
        "schedule-queued", sched.queued),
      gauge(lead === null || through === null
        ? "nothing loaded ahead"
        : `loaded through ${through}, ${fmt(lead, 1)} s ahead` + (windowS !== null ? ` (lead window ${fmt(windowS, 0)} s)` : ""),
      windowS !== null && lead !== null ? (100 * lead) / windowS : 0, "schedule-lead", lead),
    );
    if (!s?.connected) scheduleBox.append(h("p.muted.small", {}, "last report before the link went down"));
  }
  if (up) {
    const row = (k: string, v: string, test: string, value: number | null) =>
      h("div.kv", {}, h("span.k", {}, k), h("span.v", { "data-test": test, "data-value": value ?? "" }, v));
    scheduleBox.append(
      row("uplink", `sent ${up.sent}/${up.commands} · acknowledged ${up.acknowledged} · in flight ${up.in_flight}`
        + (up.expired ? ` · expired ${up.expired}` : ""), "uplink-sent", up.sent),
      row("retransmissions", String(up.retransmissions)
        + (up.schedule_full_refusals ? ` · schedule full ${up.schedule_full_refusals}` : ""), "uplink-retx", up.retransmissions),
      row("timer (ground s)", `RTO ${fmt(up.rto_s, 2)} · SRTT ${up.srtt_s === null ? "—" : fmt(up.srtt_s, 2)}`, "uplink-rto", up.rto_s),
      row("min fill margin", up.min_fill_margin_s === null ? "—" : `${fmt(up.min_fill_margin_s, 1)} s`,
        "uplink-margin", up.min_fill_margin_s),
    );
  }
}

export function renderCommands(
  el: CommandPanel,
  commands: Iterable<CommandPublic>,
  lastCancel: Record<string, unknown> | null,
  view: { pass: PassPublic; plan: PlanDocument | null; range: [number, number] | null; timeScale: number },
  tNow: number | null,
): void {
  const { pass, plan, range } = view;
  const { stageCounts, cancelNote, nextList } = el;
  const list = [...commands].sort((a, b) => a.execute_time_ns - b.execute_time_ns);
  const counts = new Map<string, number>();
  for (const c of list) counts.set(c.stage, (counts.get(c.stage) ?? 0) + 1);
  clear(stageCounts);
  // Stages in the order a command reaches them (the final ones, the outcomes, last).
  for (const stage of COMMAND_STAGES) {
    const n = counts.get(stage) ?? 0;
    const final = FINAL_STAGES.includes(stage);
    stageCounts.append(h("span.stage", { "data-stage": stage, "data-count": n, "data-final": final, style: `--c:${STAGE_COLORS[stage]}` }, `${stage} ${n}`));
  }
  // Commands sent more than once (as of the last REST load: copies raise no event; the
  // uplink's live total is under "retransmissions").
  const again = list.filter((x) => (x.transmissions ?? 0) > 1).length;
  stageCounts.append(h("span.stage", { "data-test": "resent", "data-count": again, style: `--c:${RESENT_COLOR}`, title: "sent more than once (white tick under the strip)" }, `sent ×2+ ${again}`));
  cancelNote.hidden = lastCancel === null;
  if (lastCancel !== null) {
    const d = lastCancel;
    cancelNote.textContent = `cancelled ${String(d.count)} (seq ${String(d.first_seq)}–${String(d.last_seq)}): ${String(d.reason ?? "")}`;
  }
  // The strip: one tick per command at its tag, coloured by stage; "now" in amber.
  const c = el.timeline;
  const w = c.clientWidth || 300;
  const hgt = 36;
  const dpr = devicePixelRatio;
  c.width = Math.round(w * dpr);
  c.height = Math.round(hgt * dpr);
  const g = c.getContext("2d");
    if (g && range && pass.epoch_ns !== null) {
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    g.clearRect(0, 0, w, hgt);
    const px = (t: number) => ((t - range[0]) / (range[1] - range[0])) * w;
    for (const cmd of list) {
      g.fillStyle = STAGE_COLORS[cmd.stage] ?? "#888";
      const x = px((cmd.execute_time_ns - pass.epoch_ns) / 1e9);
      g.fillRect(x, cmd.kind === "acs" ? 2 : 10, 1.5, cmd.kind === "acs" ? 6 : 22);
      if ((cmd.transmissions ?? 0) > 1) {
        g.fillStyle = RESENT_COLOR;
        g.fillRect(x, 33, 1.5, 3);
      }
    }
    if (plan) {
      g.fillStyle = "#aab";
      g.font = "9px sans-serif";
      for (const s of plan.segments) g.fillRect(px(s.t_start_s), 0, 1, hgt);
    }
    if (tNow !== null) {
      g.fillStyle = "#e8b04a";
      g.fillRect(px(tNow) - 1, 0, 2, hgt);
    }
  }
  // Next two queued and the latest three past their tag.
  clear(nextList);
  const nowNs = pass.epoch_ns !== null && tNow !== null ? pass.epoch_ns + tNow * 1e9 : null;
  const future = nowNs === null ? list.filter((x) => x.stage === "queued") : list.filter((x) => x.execute_time_ns > nowNs);
  const past = nowNs === null ? [] : list.filter((x) => x.execute_time_ns <= nowNs);
  const item = (cmd: CommandPublic, when: string) =>
    h("li", { "data-stage": cmd.stage }, h("span.tag", {}, when), ` #${cmd.seq} ${cmd.kind} `,
      h("span.stage", { style: `--c:${STAGE_COLORS[cmd.stage] ?? "#888"}` }, cmd.stage),
      cmd.reject_reason ? h("span.error", {}, ` ${cmd.reject_reason}`) : null,
      (cmd.transmissions ?? 0) > 1 ? h("span.muted", { title: "copies sent" }, ` ×${cmd.transmissions}`) : null);
  const tagOf = (cmd: CommandPublic) =>
    pass.epoch_ns === null ? "" : `t=${fmt((cmd.execute_time_ns - pass.epoch_ns) / 1e9, 2)} s`;
  for (const cmd of past.slice(-3)) nextList.append(item(cmd, tagOf(cmd)));
  for (const cmd of future.slice(0, 2)) nextList.append(item(cmd, tagOf(cmd) + (nowNs !== null ? ` (in ${fmt((cmd.execute_time_ns - nowNs) / 1e9 / view.timeScale, 1)} s)` : "")));
  if (!list.length) nextList.append(h("li.muted", {}, "No commands yet (they are made when the pass starts)."));
}
