"""A console behind (docs/console.md "A console behind"): measured and acted on by the hub's
lag watch (:meth:`server.services.console.ConsoleHub.check_lag`, every ``lag_check_s`` on the
hub's clock)."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from server.services.console_messages import ErrorMsg, LagMsg, ResyncMsg

if TYPE_CHECKING:
    from server.services.console import ConsoleHub

__all__ = ["check_lag"]

log = logging.getLogger("hikoboshi.ground.console")


def check_lag(hub: ConsoleHub) -> None:
    """Measure every console's lag (the age of its oldest unsent message) and act on it:
    tell it (``lag``), drop its bulk backlog for a ``resync``, or close it."""
    now = hub.clock.monotonic()
    limits = hub.limits
    for client in hub.consoles():
        if client.closing:
            continue
        lag = client.lag(now)
        if lag.any_s > limits.behind_drop_s:
            reason = (
                f"behind by {lag.any_s:.0f} s, more than {limits.behind_drop_s:g} s:"
                " the console does not keep up"
            )
            log.warning("console %s: %s; closed", client.actor, reason)
            client.control(ErrorMsg(reason=reason, ref_type=None))
            client.kill(1008, reason)
            continue
        dropped = client.drop_bulk() if lag.bulk_s > limits.behind_resync_s else {}
        behind = lag.any_s >= limits.behind_report_s
        due = now - client.last_lag_report >= limits.behind_report_s
        if (behind and due) or dropped or (client.reported_behind and not behind):
            client.control(
                LagMsg(
                    behind_s=round(lag.any_s, 3) if behind else 0.0,
                    queued=client.queued,
                    resync_s=limits.behind_resync_s,
                    time_ns=hub.clock.time_ns(),
                )
            )
            client.last_lag_report = now
            client.reported_behind = behind
        if dropped:
            client.resyncs += 1
            log.info(
                "console %s: behind by %.1f s, %d messages dropped: resync",
                client.actor,
                lag.bulk_s,
                sum(dropped.values()),
            )
        for sub, count in dropped.items():
            if sub.closed:
                continue
            stream = sub.stream
            client.control(
                ResyncMsg(
                    topic=stream.topic,
                    pass_id=stream.pass_id,
                    epoch=hub.epoch,
                    seq=sub.last_seq,
                    reason=(
                        f"behind by {lag.bulk_s:.1f} s, more than"
                        f" {limits.behind_resync_s:g} s: {count} messages not sent;"
                        " reload the snapshot"
                    ),
                )
            )
