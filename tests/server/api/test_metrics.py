"""``GET /metrics``: a viewer's token reads it; its gauges are the figures the services
hold (the console's), read at scrape time; requests and database commits are timed."""

from __future__ import annotations

import shutil
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from planner.limits import Severity
from server.services.metrics import LEAD_BUCKETS_S, GroundMetrics
from server.services.record_counts import REFRESH_S
from tests.support.api import OPERATOR, VIEWER, add_pass


def _samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def test_metrics_need_a_viewers_token(client: TestClient) -> None:
    assert client.get("/metrics").status_code == 401
    wrong = client.get("/metrics", headers={"Authorization": "Bearer nope-nope"})
    assert wrong.status_code == 401 and wrong.json()["error"]["code"] == "unauthorized"
    for headers in (VIEWER, OPERATOR):
        response = client.get("/metrics", headers=headers)
        assert response.status_code == 200
        assert response.headers["content-type"].startswith("text/plain; version=")
    assert "/metrics" not in client.get("/openapi.json").json()["paths"]


def test_the_gauges_are_the_services_figures(client: TestClient) -> None:
    state: Any = client.app.state  # type: ignore[attr-defined]
    status = state.link.status()  # what the console shows
    samples = _samples(client.get("/metrics", headers=VIEWER).text)
    assert samples[("hikoboshi_link_connected", ())] == float(status.connected) == 0.0
    assert samples[("hikoboshi_downlink_frames_received_total", ())] == status.frames_received
    assert samples[("hikoboshi_downlink_duplicates_total", ())] == status.duplicates
    assert samples[("hikoboshi_downlink_open_gaps", ())] == len(status.open_gaps)
    assert samples[("hikoboshi_worker_queue_capacity", ())] == state.workers.queue
    assert samples[("hikoboshi_consoles", ())] == state.console.clients == 0
    assert samples[("hikoboshi_commands", (("stage", "queued"),))] == 0.0  # no pass running
    # the one ground of its database holds the command lease (server/services/authority.py)
    authority = state.authority
    assert samples[("hikoboshi_command_lease_holder", ())] == 1.0
    assert samples[("hikoboshi_command_lease_commanding", ())] == 1.0
    assert samples[("hikoboshi_command_lease_token", ())] == authority.lease.token >= 1
    assert samples[("hikoboshi_command_lease_acquisitions_total", ())] == 1.0
    assert samples[("hikoboshi_command_lease_losses_total", ())] == 0.0
    # the database answers: nothing journaled, no outage
    assert samples[("hikoboshi_database_reachable", ())] == 1.0
    assert samples[("hikoboshi_database_journal", ())] == state.db.journal
    assert samples[("hikoboshi_database_outages_total", ())] == 0.0


def test_counts_are_counters_with_the_process_s_own_and_no_created_series(
    client: TestClient,
) -> None:
    """What only grows is a counter (``_total``), what goes up and down a gauge; the
    process's CPU, memory and descriptors and Python's GC are there; no ``_created``
    series; OpenMetrics to a client that asks for it, the text format otherwise."""
    text = client.get("/metrics", headers=VIEWER).text
    families = {f.name: f.type for f in text_string_to_metric_families(text)}
    for counter in ("hikoboshi_downlink_frames_received", "hikoboshi_downlink_duplicates",
                    "hikoboshi_downlink_retransmit_requests", "hikoboshi_database_outages",
                    "hikoboshi_command_lease_acquisitions"):  # fmt: skip
        assert families[counter] == "counter", counter
    for gauge in ("hikoboshi_link_connected", "hikoboshi_database_journal",
                  "hikoboshi_commands", "hikoboshi_uplink_retransmissions"):  # fmt: skip
        assert families.get(gauge, "gauge") == "gauge", gauge
    assert {"process_cpu_seconds", "process_resident_memory_bytes", "process_open_fds",
            "python_info", "python_gc_collections"} <= families.keys()  # fmt: skip
    assert "_created" not in text
    openmetrics = "application/openmetrics-text; version=1.0.0; charset=utf-8"
    asked = client.get("/metrics", headers={**VIEWER, "Accept": openmetrics})
    assert asked.headers["content-type"].startswith("application/openmetrics-text")
    assert asked.text.endswith("# EOF\n")
    from prometheus_client.openmetrics.parser import text_string_to_metric_families as om

    names = {f.name for f in om(asked.text)}
    assert {"hikoboshi_downlink_duplicates", "process_cpu_seconds"} <= names


def test_requests_are_timed_by_route_and_commits_by_the_database_worker(
    client: TestClient,
) -> None:
    state: Any = client.app.state  # type: ignore[attr-defined]
    for _ in range(3):
        assert client.get("/api/passes", headers=VIEWER).status_code == 200
    assert client.get("/api/passes/nope", headers=VIEWER).status_code == 404
    assert client.get("/api/passes").status_code == 401  # refused at the edge
    for method in ("BREW", "WHEN"):  # a client's own methods: one label for them all
        client.request(method, "/api/passes", headers=VIEWER)
    client.portal.call(state.db.run, lambda session: None)  # type: ignore[union-attr]
    samples = _samples(client.get("/metrics", headers=VIEWER).text)
    name = "hikoboshi_http_request_duration_seconds_count"
    ok = (("method", "GET"), ("route", "/api/passes"), ("status", "2xx"))
    assert samples[(name, ok)] == 3.0
    missing = (("method", "GET"), ("route", "/api/passes/{pass_id}"), ("status", "4xx"))
    assert samples[(name, missing)] == 1.0
    refused = (("method", "GET"), ("route", "unmatched"), ("status", "4xx"))
    assert samples[(name, refused)] == 1.0
    methods = {dict(labels)["method"] for (n, labels) in samples if n == name}
    assert methods == {"GET", "other"}
    assert samples[("hikoboshi_db_commit_seconds_count", ())] >= 1.0


def _status(**changes: Any) -> SimpleNamespace:
    base: dict[str, Any] = {
        "connected": True,
        "vehicle_mode": "nominal",
        "round_trip_s": 0.6,
        "frames_received": 1200,
        "duplicates": 7,
        "frames_behind": 3,
        "open_gaps": [(10, 12), (40, 40)],
        "frames_missing": 4,
        "retransmit_requests": 2,
        "uplink": {"retransmissions": 5, "min_fill_margin_s": 41.5},
    }
    return SimpleNamespace(**{**base, **changes})


def test_a_running_pass_as_the_collector_reads_it() -> None:
    metrics = GroundMetrics()
    metrics.sources.link_status = _status
    metrics.sources.command_stages = lambda: {"queued": 10, "sent": 4, "executed": 6}
    leads = [0.5, 3.0, 45.0, 110.0, 400.0]
    metrics.sources.uplink_leads_s = lambda: leads
    metrics.sources.workers = lambda: (2, 5, 8)
    metrics.sources.consoles = lambda: 3
    from prometheus_client import generate_latest

    samples = _samples(generate_latest(metrics.registry).decode())
    assert samples[("hikoboshi_link_connected", ())] == 1.0
    assert samples[("hikoboshi_downlink_frames_behind", ())] == 3.0
    assert samples[("hikoboshi_downlink_open_gaps", ())] == 2.0
    assert samples[("hikoboshi_downlink_frames_missing", ())] == 4.0
    assert samples[("hikoboshi_uplink_retransmissions", ())] == 5.0
    assert samples[("hikoboshi_downlink_retransmit_requests_total", ())] == 2.0
    assert ("hikoboshi_foxglove_dropped_total", ()) not in samples  # it does not run
    metrics.sources.foxglove = lambda: (4, 900)
    more = _samples(generate_latest(metrics.registry).decode())
    assert more[("hikoboshi_foxglove_dropped_total", ())] == 4.0
    assert more[("hikoboshi_foxglove_sent_total", ())] == 900.0
    assert samples[("hikoboshi_uplink_lead_min_seconds", ())] == 41.5
    assert samples[("hikoboshi_commands", (("stage", "queued"),))] == 10.0
    assert samples[("hikoboshi_commands", (("stage", "executed"),))] == 6.0
    assert samples[("hikoboshi_worker_queue_depth", ())] == 3.0
    assert samples[("hikoboshi_consoles", ())] == 3.0
    bucket = "hikoboshi_uplink_lead_seconds_bucket"
    assert samples[(bucket, (("le", "1.0"),))] == 1.0
    assert samples[(bucket, (("le", "60.0"),))] == 3.0
    assert samples[(bucket, (("le", "+Inf"),))] == 5.0
    assert samples[("hikoboshi_uplink_lead_seconds_count", ())] == 5.0
    assert samples[("hikoboshi_uplink_lead_seconds_sum", ())] == sum(leads)
    assert max(LEAD_BUCKETS_S) < 400.0  # the last lead is counted only under +Inf


def test_a_failing_source_leaves_the_scrape_answered() -> None:
    metrics = GroundMetrics()

    def broken() -> SimpleNamespace:
        raise RuntimeError("link gone")

    metrics.sources.link_status = broken
    metrics.sources.consoles = lambda: 1
    from prometheus_client import generate_latest

    text = generate_latest(metrics.registry).decode()
    assert "hikoboshi_link_connected" not in text
    assert "hikoboshi_http_request_duration_seconds" in text


def test_the_archives_counts_and_the_data_volume_are_exported(
    client: TestClient, tmp_path: Path
) -> None:
    """Passes by state and unacknowledged alarms by severity, every label present; the data
    folder's volume; refreshed at most every few seconds (the counter's injected clock)."""
    state: Any = client.app.state  # type: ignore[attr-defined]
    counter = state.record_counter
    now = [1000.0]
    counter._clock = lambda: now[0]  # the counter's clock, moved by the test
    counter.latest = None
    first = _samples(client.get("/metrics", headers=VIEWER).text)
    assert first[("hikoboshi_passes", (("state", "scheduled"),))] == 0.0
    assert {
        s for (name, labels), _ in first.items() if name == "hikoboshi_passes" for _, s in labels
    } == {"scheduled", "aos", "running", "los", "complete", "aborted", "safed"}
    severities = {
        labels: v
        for (name, labels), v in first.items()
        if name == "hikoboshi_alarms_unacknowledged"
    }
    assert {dict(labels)["severity"] for labels in severities} == {s.value for s in Severity}
    assert set(severities.values()) == {0.0}
    usage = shutil.disk_usage(tmp_path)
    assert first[("hikoboshi_data_volume_size_bytes", ())] == usage.total
    assert 0 < first[("hikoboshi_data_volume_free_bytes", ())] <= usage.total

    add_pass(client, "counted")
    now[0] += REFRESH_S / 2
    cached = _samples(client.get("/metrics", headers=VIEWER).text)
    assert cached[("hikoboshi_passes", (("state", "scheduled"),))] == 0.0  # not asked again
    now[0] += REFRESH_S / 2
    fresh = _samples(client.get("/metrics", headers=VIEWER).text)
    assert fresh[("hikoboshi_passes", (("state", "scheduled"),))] == 1.0
