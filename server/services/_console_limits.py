"""The console protocol's topics and the limits of one console and one stream
(:mod:`server.services.console`, docs/console.md "Limits")."""

from __future__ import annotations

import uuid
from dataclasses import dataclass

__all__ = [
    "ENDED_STATES",
    "EVENT_TOPICS",
    "RETIRED_KEPT",
    "STATE_TOPICS",
    "TOPICS",
    "ConsoleLimits",
    "canonical_pass",
    "event_class",
]

#: Event topics and the event kinds each carries (``None``: every kind).
EVENT_TOPICS: dict[str, tuple[str, ...] | None] = {
    # An abort cancels a pass's commands in one ``commands_cancelled`` event (count and seq
    # range), not one ``command_stage`` each: a console following stages needs it too.
    "commands": ("command_stage", "commands_cancelled"),
    "passes": ("pass_state",),
    "events": None,
}
TOPICS = ("telemetry", *EVENT_TOPICS, "link", "alarms")
#: Topics whose messages are states, not found again in the database (ring only; across
#: grounds JetStream holds them like the others).
STATE_TOPICS = ("link", "alarms")
#: A pass's states after which its telemetry stream may be retired.
ENDED_STATES = ("complete", "aborted", "safed")
#: How many retired telemetry streams' last seqs are remembered (a few ints each).
RETIRED_KEPT = 10_000


@dataclass
class ConsoleLimits:
    """What one console and one stream may hold; read when used, so a test may shrink it."""

    ring_size: int = 1024  # messages per stream kept in memory for a replay
    index_size: int = 1_000_000  # messages per stream that can be found in the database
    #: Live data unsent to one client (bytes of text) beyond which its subscription is
    #: dropped: a burst (an abort expires thousands of commands at once) fits; a console
    #: that stopped reading is found out in minutes, not hours.
    queue_bytes: int = 2 * 1024 * 1024
    max_replay: int = 4096  # messages one subscribe may replay (more: resync)
    max_subscriptions: int = 32
    max_message_bytes: int = 64 * 1024  # client -> server
    max_rate_hz: float = 1000.0
    link_poll_s: float = 1.0  # wall
    link_heartbeat_s: float = 5.0  # wall: the link status is pushed at least this often
    auth_timeout_s: float = 10.0
    # Replay of recorded passes:
    max_replays_per_console: int = 4
    max_replays: int = 32  # in the whole server (each holds its recording in memory)
    max_replay_frames: int = 200_000  # frames of one recording (~5.5 h at 10 Hz, ~70 MB)
    max_replay_factor: float = 1000.0
    max_replay_batch_frames: int = 500  # frames per message (and as-fast-as-possible batch)
    #: Replay data unsent to one console beyond which its replays hold (until half is sent).
    replay_window_bytes: int = 1024 * 1024
    replay_tick_s: float = 0.02  # wall: a real-time replay sends at most this often
    replay_report_s: float = 0.5  # wall: replay_state while frames flow, at most this often
    # A console behind (docs/console.md, "Backpressure"); times on the hub's clock:
    lag_check_s: float = 0.25  # how often each console's lag is measured
    #: A console whose oldest unsent message is older than this is sent ``lag`` (at most
    #: this often, and once more, ``behind_s: 0``, when it has caught up).
    behind_report_s: float = 0.5
    #: Bulk data (telemetry, command stages, the audit log) unsent for longer than this is
    #: dropped and each of its subscriptions told ``resync``: the console reloads the
    #: snapshot over REST and goes on live, instead of reading a backlog older than that.
    behind_resync_s: float = 2.0
    #: Anything unsent for longer than this (control messages, which jump the queue,
    #: included): the console is told why (``error``, and the close's reason) and closed.
    behind_drop_s: float = 30.0
    #: A console that acknowledges what it reads (``ack``) is handed bulk data only while
    #: what it has not acknowledged is less than what it read in the last this long (at
    #: least ``ack_window_min_bytes``): the rest waits in the server's queues, not in the
    #: socket's buffers, where a control message could not pass it nor a resync drop it.
    ack_window_s: float = 0.5
    ack_window_min_bytes: int = 4096

    @property
    def hard_cap(self) -> int:
        """Messages queued to one client, other than its subscriptions' data (which
        ``queue_bytes`` and the lag bounds hold), beyond which it is disconnected."""
        return self.max_replay + 1024


def canonical_pass(pass_id: str | None) -> str | None:
    if pass_id is None:
        return None
    try:
        return str(uuid.UUID(pass_id))
    except ValueError:
        return pass_id


def event_class(kind: str) -> str:
    """The narrowest event topic an event of ``kind`` belongs to (``events`` holds them
    all): its subject's class across grounds (server/services/jetstream.py)."""
    for topic, kinds in EVENT_TOPICS.items():
        if kinds is not None and kind in kinds:
            return topic
    return "other"
