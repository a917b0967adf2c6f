"""The spacecraft process's configuration (:class:`ProcessConfig`): the grounds it talks to
and its token, the clock's scales, the vehicle, both emulated links and the onboard
telemetry store, and the rehearsals (noise, a contact plan); checked when built. The process
itself is :class:`spacecraft.process.SpacecraftProcess`, and ``spacecraft.process`` exports
this class too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from spacecraft.contact import ContactPlan
from spacecraft.downlink import DownlinkConfig
from spacecraft.link import Garbage, LinkConfig
from spacecraft.vehicle_config import VehicleConfig

__all__ = ["ProcessConfig"]


@dataclass(frozen=True)
class ProcessConfig:
    ground_url: str
    token: str
    #: more grounds' link endpoints (hot standbys), tried in order after ``ground_url``
    standby_urls: tuple[str, ...] = ()
    time_scale: float = 1.0
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    uplink: LinkConfig = field(default_factory=LinkConfig)
    downlink: LinkConfig = field(default_factory=lambda: LinkConfig(seed=1))
    telemetry_store: DownlinkConfig = field(default_factory=DownlinkConfig)
    epoch_ns: int | None = None  # onboard clock at start; default: wall clock, whole second
    seed: int = 0
    backoff_initial_s: float = 0.2  # wall seconds
    backoff_max_s: float = 5.0
    drain_timeout_s: float = 30.0  # wall seconds
    #: where the truth log is written (None: nowhere)
    truth_log: Path | None = None
    #: windows of malformed messages toward the ground (a rehearsal of a noisy link)
    garbage: tuple[Garbage, ...] = ()
    #: the relay's windows and delays from a mission (None: always up, the links' delay)
    contact: ContactPlan | None = None
    #: between windows the onboard clock runs at most this many times wall time (None: as
    #: fast as the simulation computes); only with ``contact``
    fast_scale: float | None = None

    def __post_init__(self) -> None:
        if not 0 < self.time_scale <= 1000:
            raise ValueError(f"time_scale = {self.time_scale} must lie in (0, 1000]")
        if self.fast_scale is not None and not self.fast_scale >= self.time_scale:
            raise ValueError(
                f"fast_scale = {self.fast_scale} must be at least time_scale = {self.time_scale}"
            )
        for url in self.ground_urls:
            if not url.startswith(("ws://", "wss://")):
                raise ValueError(f"ground URL {url!r} must start with ws:// or wss://")

    @property
    def ground_urls(self) -> tuple[str, ...]:
        """Every ground this vehicle may talk to, in the order it tries them."""
        return (self.ground_url, *self.standby_urls)
