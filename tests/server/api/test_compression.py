"""Gzip on the way out (server/api/compression.py): a response of 1 KB or more is gzip'd when
the client accepts it, a small one and one to a client that does not are sent as they are,
and a stored artifact keeps its length and ETag."""

from __future__ import annotations

import gzip
import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.api.compression import MINIMUM_BYTES
from server.app import create_app
from server.settings import Settings
from tests.support.api import TOKENS, VIEWER


@pytest.fixture()
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(Settings(data_dir=tmp_path, tokens=TOKENS))) as c:
        yield c


def raw(client: TestClient, path: str, encoding: str) -> tuple[dict[str, str], bytes]:
    """The headers and the bytes on the wire (not decoded) of GET ``path``."""
    with client.stream("GET", path, headers={**VIEWER, "Accept-Encoding": encoding}) as r:
        assert r.status_code == 200, r.read()
        return dict(r.headers), b"".join(r.iter_raw())


def test_a_large_response_is_gzipped_when_asked(client: TestClient) -> None:
    plain_headers, plain = raw(client, "/openapi.json", "identity")
    headers, body = raw(client, "/openapi.json", "gzip")
    assert "content-encoding" not in plain_headers and len(plain) > MINIMUM_BYTES
    assert headers["content-encoding"] == "gzip"
    assert "accept-encoding" in headers["vary"].lower()
    assert int(headers["content-length"]) == len(body) < len(plain) / 3
    assert json.loads(gzip.decompress(body)) == json.loads(plain)


def test_a_small_response_is_sent_as_it_is(client: TestClient) -> None:
    headers, body = raw(client, "/api/health", "gzip")
    assert len(body) < MINIMUM_BYTES and "content-encoding" not in headers
    assert json.loads(body) == {"status": "ok", "command": "holder"}


def test_a_client_that_does_not_accept_gzip_gets_plain_bytes(client: TestClient) -> None:
    headers, body = raw(client, "/openapi.json", "br")
    assert "content-encoding" not in headers and body.startswith(b"{")
