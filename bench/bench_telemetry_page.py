"""What a page of raw telemetry costs the server's interpreter: the worker process
hands back either the page's model (unpickled, then validated and encoded to JSON by the
route, the encoding on the event loop) or its JSON bytes (unpickled only). Best of 5,
in this process, on a page of 5,000 rows of 40 values (4.2 MB of JSON, as the demo pass's
``telemetry?limit=5000``); the ratio is model / bytes.

    .venv/bin/python bench/bench_telemetry_page.py
"""

from __future__ import annotations

import pickle
import sys
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import best_of, emit
from pydantic import TypeAdapter

from server.schemas.telemetry import TelemetryPublic, TelemetryRowPublic

ROWS = 5000
VALUES = 40


def main() -> None:
    values = {f"v{k}": 0.123456789 * k for k in range(VALUES)}
    at = datetime(2026, 1, 1, tzinfo=UTC)
    rows = [
        TelemetryRowPublic(
            seq=k, generation_time_ns=k * 10**8, generation_time=at, values=dict(values)
        )
        for k in range(ROWS)
    ]
    page = TelemetryPublic(
        pass_id="p", mode="raw", fields=list(values), t0_ns=0, t1_ns=1, count=ROWS, rows=rows
    )
    adapter = TypeAdapter(TelemetryPublic)
    as_model = pickle.dumps(("ok", page))
    body = adapter.dump_json(page)
    as_bytes = pickle.dumps(("ok", body))

    def model_in_server() -> None:
        _, received = pickle.loads(as_model)
        adapter.dump_json(adapter.validate_python(received))

    def encode_only() -> None:
        adapter.dump_json(adapter.validate_python(page))

    def bytes_in_server() -> None:
        pickle.loads(as_bytes)

    model_s, encode_s, bytes_s = (
        best_of(f) for f in (model_in_server, encode_only, bytes_in_server)
    )
    emit(
        "telemetry_page",
        {
            "json_bytes": len(body),
            "model_unpickle_and_encode_s": model_s,
            "of_which_validate_and_encode_s": encode_s,
            "bytes_unpickle_s": bytes_s,
            "ratio_model_to_bytes": model_s / bytes_s,
        },
        {"bytes_cheaper": bytes_s < model_s},
    )


if __name__ == "__main__":
    main()
