"""Emulation of one direction of the ground-TDRS-spacecraft relay link (SPEC 6).

Deterministic and free of I/O: the caller (an asyncio process) tells the emulator when it
sends a message and how big it is; the emulator answers when the message arrives, or that it
never does, and the caller schedules the delivery itself. One emulator serves one direction;
the uplink and the downlink each get their own, with different seeds.

Units and time base
-------------------
Every time is in ONBOARD seconds since the link's epoch (``now_s``, ``start_s``, the returned
delivery time); the process converts to and from wall-clock time with its own time scale.
Sizes are bytes, ``bandwidth_bps`` is BYTES per second.

The model, for a message handed over at ``now_s`` with ``size_bytes``
------------------------------------------------------------------------
1. Serialisation: the transmitter sends one message after another. Transmission starts at
   ``tx_start_s = max(now_s, end of the previous transmission)`` and lasts
   ``size_bytes / bandwidth_bps`` (zero when the bandwidth is unlimited). The queueing delay
   is ``tx_start_s - now_s``, the wait behind earlier messages; ``stats.max_queue_delay_s``
   is its largest value. Every message occupies the transmitter, including those the link
   later drops: the sender cannot know.
2. Propagation: ``delay_s + e``, with ``e ~ N(0, jitter_s**2)`` clipped to ``[-5, +5]``
   standard deviations, and the sum clipped at 0 so a message never arrives before it left.
   Arrival is the end of transmission plus the propagation delay.
3. Order (``preserve_order``): a relay delivers in order, so a message is never delivered
   before one sent earlier; its arrival is raised to that of the last delivered message
   (jitter can only delay). Equal delivery times can occur (e.g. no jitter and no bandwidth
   cap); the caller breaks such ties by send order.
4. Outages (LOS): the link is down on ``[start_s, end_s)`` of each outage. A message is lost
   to an outage if the link is down at ANY instant from ``now_s`` to its delivery time,
   both ends included: sent during LOS, arriving during LOS, or in flight when LOS begins
   (even an outage shorter than the delay and entirely inside the flight kills it).
5. Random loss: each message is dropped with probability ``loss``, independently.
6. Contact plan (``contact``, :mod:`spacecraft.contact`, from a mission's geometry): when
   given, the link is up only inside its windows and the propagation delay is the plan's at
   the end of transmission (the ground's processing delay plus the path's light time) in
   place of ``delay_s``. A message is lost to LOS (``dropped_outage``) unless it is sent
   inside a window and arrives before that window's loss of signal: nothing crosses
   outside a window. Hand-given outages apply as well.

A message lost to both an outage and the random draw counts as ``dropped_outage``. Every
``send`` consumes exactly one uniform and one normal draw from the generator, whatever the
outcome, so the same config and the same sequence of calls give exactly the same results, and
changing the outages or the loss does not reshuffle the jitter of the other messages.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from spacecraft.contact import ContactPlan

__all__ = [
    "Garbage",
    "LinkConfig",
    "LinkEmulator",
    "LinkStats",
    "Outage",
    "load_link_config",
    "parse_garbage",
    "parse_outage",
]

_JITTER_CLIP_SIGMA = 5.0


def _is_real(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _check_real(name: str, value: object, allowed: str, ok: bool) -> None:
    """Raise a ValueError naming the field, the value and the allowed range unless ``ok``."""
    if not _is_real(value) or not ok:
        raise ValueError(f"{name} = {value!r} is outside the allowed range {allowed}")


@dataclass(frozen=True)
class Outage:
    """A loss-of-signal window ``[start_s, end_s)``, onboard seconds since the link's epoch."""

    start_s: float
    end_s: float

    def __post_init__(self) -> None:
        for name in ("start_s", "end_s"):
            value = getattr(self, name)
            ok = _is_real(value) and math.isfinite(value)
            _check_real(f"outage {name}", value, "(-inf, inf) s, finite", ok)
        if not self.start_s < self.end_s:
            raise ValueError(
                f"outage end_s = {self.end_s!r} must be greater than start_s = {self.start_s!r}"
            )

    def contains(self, t_s: float) -> bool:
        """Whether the link is down at ``t_s`` because of this outage."""
        return self.start_s <= t_s < self.end_s

    def overlaps(self, from_s: float, to_s: float) -> bool:
        """Whether the link is down at some instant of the closed interval ``[from_s, to_s]``."""
        return self.start_s <= to_s and self.end_s > from_s


@dataclass(frozen=True)
class Garbage:
    """Noise toward the ground: malformed messages (:mod:`spacecraft.garbage`) at
    ``rate`` a WALL-clock second on ``[start_s, end_s)`` onboard seconds since the link's
    epoch, put on the link at its ground end (no delay, no loss: the relay's own noise)."""

    start_s: float
    end_s: float
    rate: float

    def __post_init__(self) -> None:
        Outage(self.start_s, self.end_s)  # the same window rules
        ok = _is_real(self.rate) and math.isfinite(self.rate) and 0 < self.rate <= 10_000
        _check_real("garbage rate", self.rate, "(0, 10000] messages per wall s", ok)

    def contains(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.end_s


@dataclass(frozen=True)
class LinkConfig:
    """Parameters of one link direction; defaults from SPEC 6. Units as in the module docstring."""

    delay_s: float = 3.0  # one-way, ground to spacecraft via the relay (SPEC 6)
    jitter_s: float = 0.05  # standard deviation of the Gaussian jitter (SPEC 6)
    loss: float = 0.0  # probability each message is dropped, [0, 1)
    outages: tuple[Outage, ...] = ()
    bandwidth_bps: float | None = None  # bytes per second; None = unlimited
    preserve_order: bool = True
    seed: int = 0
    #: windows and delays from a mission's geometry (None: always up, ``delay_s``)
    contact: ContactPlan | None = None

    def __post_init__(self) -> None:
        d, j, p, b = self.delay_s, self.jitter_s, self.loss, self.bandwidth_bps
        _check_real("delay_s", d, "[0, inf) s", _is_real(d) and math.isfinite(d) and d >= 0)
        _check_real("jitter_s", j, "[0, inf) s", _is_real(j) and math.isfinite(j) and j >= 0)
        _check_real("loss", p, "[0, 1)", _is_real(p) and 0 <= p < 1)
        if b is not None:
            _check_real(
                "bandwidth_bps",
                b,
                "(0, inf) bytes/s, or None for unlimited",
                _is_real(b) and math.isfinite(b) and b > 0,
            )
        if not isinstance(self.preserve_order, bool):
            raise ValueError(f"preserve_order = {self.preserve_order!r} must be true or false")
        s = self.seed
        if not isinstance(s, int) or isinstance(s, bool) or s < 0:
            raise ValueError(f"seed = {s!r} is outside the allowed range: integers >= 0")
        if not isinstance(self.outages, tuple) or not all(
            isinstance(o, Outage) for o in self.outages
        ):
            raise ValueError(f"outages = {self.outages!r} must be a tuple of Outage")


@dataclass(frozen=True)
class LinkStats:
    """Counters of one emulator; ``sent == delivered + dropped_loss + dropped_outage``."""

    sent: int = 0
    delivered: int = 0
    dropped_loss: int = 0
    dropped_outage: int = 0
    max_queue_delay_s: float = 0.0  # longest wait behind earlier messages, onboard s


class LinkEmulator:
    """One direction of the relay link; see the module docstring for the model."""

    def __init__(self, config: LinkConfig) -> None:
        self._config = config
        self._rng = np.random.default_rng(config.seed)
        self._last_send_s = -math.inf
        self._tx_free_s = -math.inf  # when the transmitter finishes its current message
        self._last_delivery_s = -math.inf  # of the last DELIVERED message (ordering floor)
        self._stats = LinkStats()

    @property
    def config(self) -> LinkConfig:
        return self._config

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the counters."""
        return self._stats

    def add_outage(self, outage: Outage) -> None:
        """Add a loss-of-signal window from now on (an unplanned LOS, or one placed relative
        to something only known at run time, such as a pass's epoch).

        It must start no earlier than the last message handed over: the fate of a message is
        drawn when it is sent, so a window reaching back before it would be applied to some
        messages and not to others. Messages already in flight keep the fate they were given.
        """
        if not isinstance(outage, Outage):
            raise ValueError(f"outage = {outage!r} must be an Outage")
        if outage.start_s < self._last_send_s:
            raise ValueError(
                f"outage start_s = {outage.start_s!r} s is before the last message sent at "
                f"{self._last_send_s!r} s; an outage can only be added from now on"
            )
        self._config = replace(self._config, outages=(*self._config.outages, outage))

    def is_up(self, t_s: float) -> bool:
        """Whether the link is up at onboard time ``t_s`` (down on each ``[start_s, end_s)``
        and, with a contact plan, outside its windows)."""
        contact = self._config.contact
        if contact is not None and not contact.is_up(t_s):
            return False
        return not any(o.contains(t_s) for o in self._config.outages)

    def send(self, now_s: float, size_bytes: int) -> float | None:
        """Hand over a message at onboard time ``now_s``.

        Returns the onboard delivery time in seconds, or ``None`` if the link drops it (random
        loss, or an outage at any instant from ``now_s`` to delivery). ``now_s`` must not go
        backwards between calls; ``size_bytes`` must be >= 0.
        """
        cfg = self._config
        if not (_is_real(now_s) and math.isfinite(now_s)):
            raise ValueError(f"now_s = {now_s!r} must be a finite number of onboard seconds")
        if now_s < self._last_send_s:
            raise ValueError(
                f"now_s = {now_s!r} s is earlier than the previous send at "
                f"{self._last_send_s!r} s; sends must come in onboard-time order"
            )
        if isinstance(size_bytes, bool) or not isinstance(size_bytes, int) or size_bytes < 0:
            raise ValueError(f"size_bytes = {size_bytes!r} must be an integer >= 0")
        self._last_send_s = now_s

        # Exactly one uniform and one normal per message, whatever the outcome (determinism).
        u = float(self._rng.random())
        z = float(self._rng.standard_normal())

        tx_start_s = max(now_s, self._tx_free_s)
        serialise_s = 0.0 if cfg.bandwidth_bps is None else size_bytes / cfg.bandwidth_bps
        self._tx_free_s = tx_start_s + serialise_s
        queue_delay_s = tx_start_s - now_s

        jitter_s = cfg.jitter_s * min(max(z, -_JITTER_CLIP_SIGMA), _JITTER_CLIP_SIGMA)
        delay_s = cfg.delay_s
        los_s = math.inf  # the loss of signal of the window carrying the message
        if cfg.contact is not None:
            window = cfg.contact.window_at(now_s)
            if window is None:
                los_s = -math.inf  # sent outside every window
            else:
                delay_s = window.delay_at(self._tx_free_s)
                los_s = window.end_s
        arrival_s = self._tx_free_s + max(delay_s + jitter_s, 0.0)
        if cfg.preserve_order:
            arrival_s = max(arrival_s, self._last_delivery_s)

        st = self._stats = replace(
            self._stats,
            sent=self._stats.sent + 1,
            max_queue_delay_s=max(self._stats.max_queue_delay_s, queue_delay_s),
        )
        if arrival_s >= los_s or any(o.overlaps(now_s, arrival_s) for o in cfg.outages):
            self._stats = replace(st, dropped_outage=st.dropped_outage + 1)
            return None
        if u < cfg.loss:
            self._stats = replace(st, dropped_loss=st.dropped_loss + 1)
            return None
        self._stats = replace(st, delivered=st.delivered + 1)
        self._last_delivery_s = arrival_s
        return arrival_s


# --- configuration from files and the command line -------------------------------------------

_KEYS = frozenset(f.name for f in fields(LinkConfig)) - {"contact"}  # from a mission only
_TABLES = ("link", "uplink", "downlink")


def _outages_from_toml(where: str, value: object) -> tuple[Outage, ...]:
    if not isinstance(value, list):
        raise ValueError(f"{where} outages must be an array of {{start_s, end_s}} tables")
    outages = []
    for i, item in enumerate(value):
        if not isinstance(item, dict) or set(item) != {"start_s", "end_s"}:
            raise ValueError(
                f"{where} outages[{i}] = {item!r} must be a table with exactly start_s and end_s"
            )
        try:
            outages.append(Outage(item["start_s"], item["end_s"]))
        except ValueError as exc:
            raise ValueError(f"{where} outages[{i}]: {exc}") from None
    return tuple(outages)


def _table(path: Path, doc: dict[str, Any], name: str) -> dict[str, Any]:
    table = doc.get(name, {})
    if not isinstance(table, dict):
        raise ValueError(f"{path}: [{name}] must be a table")
    unknown = sorted(set(table) - _KEYS)
    if unknown:
        raise ValueError(
            f"{path}: [{name}] has unknown key(s) {', '.join(unknown)}; "
            f"allowed: {', '.join(sorted(_KEYS))}"
        )
    where = f"{path}: [{name}]"
    if "outages" in table:
        table = {**table, "outages": _outages_from_toml(where, table["outages"])}
    return table


def load_link_config(path: Path) -> tuple[LinkConfig, LinkConfig]:
    """Read ``(uplink, downlink)`` configs from a TOML file.

    Three optional tables: ``[link]`` holds keys both directions inherit; ``[uplink]`` and
    ``[downlink]`` override them key by key (an ``outages`` array in a direction REPLACES the
    shared one). Keys are the fields of :class:`LinkConfig`; outages are arrays of
    ``{start_s, end_s}`` tables; omit ``bandwidth_bps`` for unlimited. Seeds: a direction
    that names its own ``seed`` gets it; otherwise, with the shared seed ``s`` (default 0),
    the uplink gets ``s`` and the downlink ``s + 1``, so the two never draw the same numbers
    by accident. Unknown tables or keys and out-of-range values raise ValueError naming the
    file, the table, the key and the allowed range.
    """
    try:
        with path.open("rb") as f:
            doc = tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    unknown = sorted(set(doc) - set(_TABLES))
    if unknown:
        raise ValueError(
            f"{path}: unknown table(s) {', '.join(unknown)}; allowed: {', '.join(_TABLES)}"
        )
    shared = _table(path, doc, "link")
    try:
        LinkConfig(**shared)  # report a bad shared value against [link], not a direction
    except ValueError as exc:
        raise ValueError(f"{path}: [link] {exc}") from None
    base_seed = shared.get("seed", 0)
    configs = []
    for offset, name in enumerate(("uplink", "downlink")):
        own = _table(path, doc, name)
        merged = {**shared, **own}
        if "seed" not in own:
            merged["seed"] = base_seed + offset
        try:
            configs.append(LinkConfig(**merged))
        except ValueError as exc:
            raise ValueError(f"{path}: [{name}] {exc}") from None
    return configs[0], configs[1]


def parse_outage(text: str) -> Outage:
    """Parse ``"START:END"`` (onboard seconds, e.g. ``"100:130"``) into an :class:`Outage`."""
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        start_s, end_s = float(parts[0]), float(parts[1])
    except ValueError:
        raise ValueError(f"outage {text!r} is not START:END in seconds (e.g. 100:130)") from None
    try:
        return Outage(start_s, end_s)
    except ValueError as exc:
        raise ValueError(f"outage {text!r}: {exc}") from None


def parse_garbage(text: str) -> Garbage:
    """Parse ``"START:END:RATE"`` (onboard seconds, messages per wall second, e.g.
    ``"60:660:400"``) into a :class:`Garbage`."""
    parts = text.split(":")
    try:
        if len(parts) != 3:
            raise ValueError
        start_s, end_s, rate = (float(p) for p in parts)
    except ValueError:
        raise ValueError(
            f"garbage {text!r} is not START:END:RATE (onboard s, messages per wall s, "
            "e.g. 60:660:400)"
        ) from None
    try:
        return Garbage(start_s, end_s, rate)
    except ValueError as exc:
        raise ValueError(f"garbage {text!r}: {exc}") from None
