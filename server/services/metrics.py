"""The ground's Prometheus metrics (``GET /metrics``, docs/operations.md "Metrics").

Nothing on the live path is counted twice: the figures the console shows (the link's state,
the downlink's counts, the running pass's uplink and commands by stage, the worker pool's
and the consoles' numbers) are read at scrape time from the services that already hold
them, by :class:`GroundCollector`; the archive's passes by state and its unacknowledged
alarms come from one grouped count, refreshed at most every few seconds in a thread
(:mod:`server.services.record_counts`), and the data folder's volume from the file system;
only what no service keeps is observed as it happens,
into prometheus-client's own histograms: each HTTP request's latency by route
(``server/api/metrics.py``) and each database commit's (the link's database worker,
``server/services/dbworker.py``). One registry per application (tests build many).
"""

from __future__ import annotations

import logging
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from prometheus_client import (
    CollectorRegistry,
    GCCollector,
    Histogram,
    PlatformCollector,
    ProcessCollector,
    disable_created_metrics,
)
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
from prometheus_client.registry import Collector

from server.services.command_stages import STAGE_RANK
from server.services.record_counts import RecordCounts

__all__ = ["LEAD_BUCKETS_S", "GroundCollector", "GroundMetrics", "Sources"]

log = logging.getLogger("hikoboshi.ground.metrics")

# No ``_created`` series beside each counter and histogram: a gauge of when it was made,
# which no alert reads (prometheus-client's switch; for the whole process).
disable_created_metrics()  # type: ignore[no-untyped-call]

#: Onboard s: the uplink lead's histogram buckets (the lead window is 120 s by default).
LEAD_BUCKETS_S = (1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 60.0, 90.0, 120.0, 180.0, 300.0)


@dataclass
class Sources:
    """Where the figures are read at scrape time: each a callable, None before the
    application has started (then its metrics are left out)."""

    link_status: Callable[[], Any] | None = None
    command_stages: Callable[[], dict[str, int]] | None = None
    uplink_leads_s: Callable[[], list[float]] | None = None
    workers: Callable[[], tuple[int, int, int]] | None = None  # running, admitted, queue
    consoles: Callable[[], int] | None = None
    #: the command lease (server.services.authority.CommandAuthority.status and its counts)
    authority: Callable[[], dict[str, Any]] | None = None
    #: the database as the command path sees it (server.services.db_outage.Outage.status)
    database: Callable[[], dict[str, Any]] | None = None
    #: the Foxglove live view's (dropped, sent); None when it does not run
    foxglove: Callable[[], tuple[int, int] | None] | None = None
    #: the archive's latest counts (server.services.record_counts); None before the first
    records: Callable[[], RecordCounts | None] | None = None
    #: the folder the recordings, reports and (SQLite) database are kept in
    data_dir: Path | None = None


def _gauge(name: str, doc: str, value: float | None) -> Iterator[Metric]:
    if value is not None:
        yield GaugeMetricFamily(name, doc, value=float(value))


def _counter(name: str, doc: str, value: float | None) -> Iterator[Metric]:
    """A count that only grows (exposed as ``name_total``)."""
    if value is not None:
        yield CounterMetricFamily(name, doc, value=float(value))


class GroundCollector(Collector):
    """The figures the services hold, read when Prometheus scrapes."""

    def __init__(self, sources: Sources) -> None:
        self.sources = sources

    def collect(self) -> Iterator[Metric]:
        try:
            yield from self._collect()
        except Exception:  # a scrape never takes the service down, nor answers 500
            log.exception("collecting the metrics failed")

    def _collect(self) -> Iterator[Metric]:
        s = self.sources
        if s.link_status is not None:
            st = s.link_status()
            yield from _gauge(
                "hikoboshi_link_connected",
                "1 when the spacecraft's link is connected",
                st.connected,
            )
            yield from _gauge(
                "hikoboshi_vehicle_safe",
                "1 when the vehicle reports on-board safing (SAFE)",
                st.vehicle_mode == "safe",
            )
            yield from _gauge(
                "hikoboshi_link_round_trip_seconds",
                "The link's measured round trip (wall s)",
                st.round_trip_s,
            )
            yield from _counter(
                "hikoboshi_downlink_frames_received",
                "Telemetry frames held by the ground (since the service started; from 0 again "
                "when a new spacecraft process numbers its frames from 0)",
                st.frames_received,
            )
            yield from _counter(
                "hikoboshi_downlink_duplicates",
                "Telemetry frames received again and dropped",
                st.duplicates,
            )
            yield from _gauge(
                "hikoboshi_downlink_frames_behind",
                "Frames the vehicle has made that the ground does not hold yet (estimated)",
                st.frames_behind,
            )
            yield from _gauge(
                "hikoboshi_downlink_open_gaps", "Gaps in the frames held", len(st.open_gaps)
            )
            yield from _gauge(
                "hikoboshi_downlink_frames_missing",
                "Frames inside the gaps in the frames held",
                st.frames_missing,
            )
            yield from _counter(
                "hikoboshi_downlink_retransmit_requests",
                "Retransmit requests sent to the vehicle",
                st.retransmit_requests,
            )
            uplink = st.uplink or {}
            yield from _gauge(
                "hikoboshi_uplink_retransmissions",
                "Commands sent again in the running pass",
                uplink.get("retransmissions"),
            )
            yield from _gauge(
                "hikoboshi_uplink_lead_min_seconds",
                "The running pass's smallest uplink lead (onboard s before its tag)",
                uplink.get("min_fill_margin_s"),
            )
        if s.command_stages is not None:
            stages = s.command_stages()
            family = GaugeMetricFamily(
                "hikoboshi_commands",
                "The running pass's commands by stage",
                labels=["stage"],
            )
            for stage in sorted(STAGE_RANK, key=STAGE_RANK.__getitem__):
                family.add_metric([stage], float(stages.get(stage, 0)))
            yield family
        if s.uplink_leads_s is not None:
            leads = s.uplink_leads_s()
            buckets = [(str(b), float(sum(1 for x in leads if x <= b))) for b in LEAD_BUCKETS_S]
            buckets.append(("+Inf", float(len(leads))))
            yield HistogramMetricFamily(
                "hikoboshi_uplink_lead_seconds",
                "The running pass's uplink leads: onboard s between each acknowledged "
                "command's arrival on board and its tag",
                buckets=buckets,
                sum_value=float(sum(leads)),
            )
        if s.workers is not None:
            running, admitted, queue = s.workers()
            yield from _gauge(
                "hikoboshi_worker_jobs_running", "Job processes running (planning, reads)", running
            )
            yield from _gauge(
                "hikoboshi_worker_queue_depth",
                "Jobs admitted and waiting for a worker process",
                max(0, admitted - running),
            )
            yield from _gauge(
                "hikoboshi_worker_queue_capacity", "Jobs that may wait (worker_queue)", queue
            )
        if s.consoles is not None:
            yield from _gauge("hikoboshi_consoles", "Console websockets connected", s.consoles())
        if s.authority is not None:
            yield from self._authority(s.authority())
        if s.database is not None:
            yield from self._database(s.database())
        yield from self._records(None if s.records is None else s.records())
        if s.data_dir is not None:
            yield from self._volume(s.data_dir)
        counts = None if s.foxglove is None else s.foxglove()
        if counts is not None:
            dropped, sent = counts
            yield from _counter(
                "hikoboshi_foxglove_dropped",
                "Live items the Foxglove view dropped because its thread was behind",
                dropped,
            )
            yield from _counter(
                "hikoboshi_foxglove_sent", "Messages the Foxglove live view sent", sent
            )

    @staticmethod
    def _records(counts: RecordCounts | None) -> Iterator[Metric]:
        if counts is None:
            return
        passes = GaugeMetricFamily(
            "hikoboshi_passes", "Passes in the archive by state", labels=["state"]
        )
        for state, n in counts.passes.items():
            passes.add_metric([state], float(n))
        yield passes
        alarms = GaugeMetricFamily(
            "hikoboshi_alarms_unacknowledged",
            "Alarms no operator has acknowledged, by the severity they reached (raised or "
            "latched after clearing)",
            labels=["severity"],
        )
        for severity, n in counts.unacknowledged_alarms.items():
            alarms.add_metric([severity], float(n))
        yield alarms

    @staticmethod
    def _volume(folder: Path) -> Iterator[Metric]:
        try:
            usage = shutil.disk_usage(folder)
        except OSError:  # not made yet, or gone: nothing to say of its volume
            return
        yield from _gauge(
            "hikoboshi_data_volume_free_bytes",
            "Bytes free to the service on the volume of its data folder",
            usage.free,
        )
        yield from _gauge(
            "hikoboshi_data_volume_size_bytes",
            "Size of the volume of the data folder, bytes",
            usage.total,
        )

    @staticmethod
    def _database(d: dict[str, Any]) -> Iterator[Metric]:
        yield from _gauge(
            "hikoboshi_database_reachable",
            "1 when the command path's database answers, 0 during an outage",
            d["reachable"],
        )
        yield from _gauge(
            "hikoboshi_database_journal",
            "The database worker's queue: command-path writes waiting for the database "
            "(queued or in a transaction; the journal during an outage)",
            d["journal"],
        )
        yield from _gauge(
            "hikoboshi_database_journal_peak",
            "The most writes the journal held in the last outage",
            d["journal_peak"],
        )
        yield from _gauge(
            "hikoboshi_database_last_outage_seconds",
            "How long the last database outage lasted (wall s)",
            d["last_down_s"],
        )
        yield from _gauge(
            "hikoboshi_database_last_replay_seconds",
            "How long replaying the last outage's journal took (wall s)",
            d["last_replay_s"],
        )
        for name, key, doc in (
            ("outages", "outages", "Database outages the command path rode through"),
            ("journal_refused", "refused", "Writes refused because the journal was full"),
        ):
            family = CounterMetricFamily(f"hikoboshi_database_{name}", doc)
            family.add_metric([], float(d[key]))
            yield family

    @staticmethod
    def _authority(a: dict[str, Any]) -> Iterator[Metric]:
        yield from _gauge(
            "hikoboshi_command_lease_holder",
            "1 when this ground holds the vehicle's command lease, 0 for a standby",
            a["role"] == "holder",
        )
        yield from _gauge(
            "hikoboshi_command_lease_commanding",
            "1 when this ground may send to the vehicle now (holder, lease renewed in time)",
            a["commanding"],
        )
        yield from _gauge(
            "hikoboshi_command_lease_token", "The fencing token this ground holds", a["token"]
        )
        yield from _gauge(
            "hikoboshi_command_lease_database_reachable",
            "1 when the lease's last read or renewal reached the database",
            a["database_reachable"],
        )
        for name, doc in (
            ("acquisitions", "Times this ground acquired the command lease (takeovers)"),
            ("losses", "Times another ground took the lease from this one"),
            ("renewal_failures", "Lease renewals that did not reach the database"),
        ):
            family = CounterMetricFamily(f"hikoboshi_command_lease_{name}", doc)
            family.add_metric([], float(a[name]))
            yield family


class GroundMetrics:
    """One application's registry: the collector, and the histograms observed as things
    happen."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        self.sources = Sources()
        self.registry.register(GroundCollector(self.sources))
        # the process's own: CPU, memory, file descriptors; Python's version and its GC
        ProcessCollector(registry=self.registry)
        PlatformCollector(registry=self.registry)
        GCCollector(registry=self.registry)
        self.request_seconds = Histogram(
            "hikoboshi_http_request_duration_seconds",
            "HTTP requests' latency (wall s) by method, route and status class",
            ["method", "route", "status"],
            registry=self.registry,
        )
        self.db_commit_seconds = Histogram(
            "hikoboshi_db_commit_seconds",
            "The link's database worker: each transaction's commit (wall s)",
            buckets=(0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0),
            registry=self.registry,
        )
