"""The Foxglove live view: two clients receive ``/tf`` and ``/events`` while a real pass
flies through the real ground (uvicorn, loopback) from the spacecraft process at 10x, behind
the gate (server/api/foxglove_gate.py) with the viewer's token: Foxglove's own client
(``@foxglove/ws-protocol`` in Node, tests/clients, offering only ``foxglove.websocket.v1``)
and a protocol client of ours (the ``websockets`` package, offering both names); the gate
refuses a handshake without a viewer's token or without a Foxglove subprotocol; and without
the extra, ``--foxglove-port`` is refused with one line naming it."""

from __future__ import annotations

import asyncio
import json
import shutil
import subprocess
import sys
from pathlib import Path

import jsonschema_rs
import pytest
from typer.testing import CliRunner

from hikoboshi.cli import app
from server.services.recordings import load_recording
from server.storage import repository as repo
from server.storage.db import sqlite_url
from tests.server.link.foxglove_client import Received, listen
from tests.server.link.harness import (
    VIEWER,
    in_contact,
    running_ground,
    settled,
    spacecraft,
    start_pass,
    store_pass,
    wait_for,
)
from tests.support.foxglove_schemas import FOXGLOVE_FRAME_TRANSFORMS, FOXGLOVE_LOG

pytestmark = pytest.mark.realtime  # flies a vehicle or serves a live link in wall time

TOPICS = {"/tf", "/events", "/scene", "/robot_description"}
CLIENTS = Path(__file__).resolve().parents[2] / "clients"  # tests/clients: npm, locked


def _reap(node: subprocess.Popen[str]) -> None:
    """The client process ended and its pipes closed, whatever happened to the test."""
    if node.poll() is None:
        node.kill()
    node.wait(timeout=30)  # a guard: a killed process ends at once
    for pipe in (node.stdin, node.stdout, node.stderr):
        if pipe is not None and not pipe.closed:
            pipe.close()


def official_client(url: str, token: str) -> subprocess.Popen[str]:
    """Foxglove's own client in Node, subscribed to every channel (tests/clients/
    foxglove_subscribe.mjs): it prints a line once subscribed, and its counts once it has
    as many ``/tf`` messages as standard input says (then closed)."""
    node = shutil.which("node")
    assert node is not None, "node is missing: scripts/setup.sh --test installs it"
    assert (CLIENTS / "node_modules" / "@foxglove" / "ws-protocol").is_dir(), (
        "tests/clients is not installed: scripts/setup.sh --test"
    )
    return subprocess.Popen(
        [node, str(CLIENTS / "foxglove_subscribe.mjs"), url, token],
        cwd=CLIENTS,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_a_foxglove_client_receives_tf_and_events_during_a_pass(tmp_path: Path) -> None:
    pytest.importorskip("foxglove", reason="the foxglove extra (hikoboshi[foxglove])")
    received = Received()
    official: dict[str, object] = {}

    async def scenario(ws_url: str, ground_url: str, pass_id: str) -> None:
        subscribed = asyncio.Event()
        # ours presents the token in the URL, as the Foxglove app does; Foxglove's own client
        # in the Authorization header: both ways in one pass
        viewer = VIEWER["Authorization"].removeprefix("Bearer ")
        client = asyncio.create_task(
            listen(f"{ws_url}/?token={viewer}", TOPICS, received, subscribed)
        )
        node = official_client(ws_url, viewer)
        try:
            assert node.stdout is not None and node.stdin is not None
            line = await asyncio.wait_for(asyncio.to_thread(node.stdout.readline), 60.0)  # guard
            assert json.loads(line or "{}").get("event") == "subscribed", (line, node.stderr)
            # both clients subscribed before the vehicle flies; a client that failed says why
            waiting = asyncio.create_task(subscribed.wait())
            await asyncio.wait({client, waiting}, timeout=60.0, return_when=asyncio.FIRST_COMPLETED)
            waiting.cancel()
            if client.done():
                client.result()  # its error, if it ended
            assert subscribed.is_set(), "our client did not subscribe in 60 s (a hang guard)"
            process, _ = spacecraft(ground)
            async with in_contact(process, ground_url) as rest:
                await start_pass(rest, pass_id, "fox-1")
                await wait_for(lambda: settled(ground, pass_id), 60.0, "the pass settled")

                def completed_seen() -> bool:
                    return any(
                        '"to": "complete"' in d["message"] for _, d in received.json("/events")
                    )

                await wait_for(completed_seen, 20.0, "the pass's completion on /events")

                def every_frame_seen() -> bool:  # the view's queue and the SDK's are FIFOs
                    with ground.readers() as session:
                        stored = repo.count_frames(session=session, pass_id=pass_id)
                    return len(received.messages.get("/tf", [])) >= stored

                await wait_for(every_frame_seen, 20.0, "a /tf message for every stored frame")
            with ground.readers() as session:  # the client waits for every one of them
                frames = repo.count_frames(session=session, pass_id=pass_id)
            done = asyncio.to_thread(node.communicate, f"{frames}\n")
            out, err = await asyncio.wait_for(done, 30.0)  # a guard
            assert node.returncode == 0, err
            official.update(json.loads(out.strip().splitlines()[-1]))
        finally:
            _reap(node)
            client.cancel()
            await asyncio.gather(client, return_exceptions=True)

    with running_ground(sqlite_url(tmp_path), foxglove_port=0) as ground:
        live = ground.app.state.foxglove
        pass_id = store_pass(ground.sessions, "fox-1", (6.0, -3.0, 0.0, 6.0, 0.0, 0.0), 2.0)
        gate = ground.app.state.foxglove_gate
        asyncio.run(scenario(f"ws://127.0.0.1:{gate.port}", ground.url, pass_id))
        with ground.readers() as session:
            stored = load_recording(session=session, pass_id=pass_id).frames.generation_time_ns
        dropped = live.dropped

    # Foxglove's own client, on the protocol's first name: every channel, every frame
    assert received.subprotocol == "foxglove.sdk.v1"
    assert official["subprotocol"] == "foxglove.websocket.v1"
    assert official["channels"] == {t: c["schemaName"] for t, c in received.channels.items()}
    counts = official["counts"]
    assert isinstance(counts, dict)
    assert counts["/tf"] == len(stored)  # advertised before the pass: every frame's
    assert 0 < counts["/plot/joints"] <= len(stored)  # advertised at the pass's first frame
    assert counts["/events"] == len(received.messages["/events"]) > 0
    assert counts["/robot_description"] >= 1 and counts["/scene"] > 10

    channels = received.channels
    assert channels["/tf"]["schemaName"] == "foxglove.FrameTransforms"
    assert channels["/events"]["schemaName"] == "foxglove.Log"
    assert {channels[t]["encoding"] for t in ("/tf", "/events")} == {"json"}
    assert channels["/scene"]["schemaName"] == "foxglove.SceneUpdate"
    assert {"/plot/joints", "/plot/base", "/plot/wheels", "/plot/prediction"} <= set(channels)

    # /tf: one message per frame stored for the pass, at its generation time, each in
    # Foxglove's published schema with the orbit -> base_link edge first
    assert dropped == 0
    tf = received.json("/tf")
    validator = jsonschema_rs.validator_for(FOXGLOVE_FRAME_TRANSFORMS)
    for log_ns, doc in tf:
        validator.validate(doc)
        first = doc["transforms"][0]
        assert (first["parent_frame_id"], first["child_frame_id"]) == ("orbit", "base_link")
        stamp = first["timestamp"]
        assert stamp["sec"] * 10**9 + stamp["nsec"] == log_ns
    assert len(stored) > 40
    assert sorted(t for t, _ in tf) == sorted(stored.tolist())
    children = {t["child_frame_id"] for t in tf[-1][1]["transforms"]}
    assert {"base_link", "link1", "link6", "hand"} <= children

    # /events: the pass's transitions as foxglove.Log, at their ground times
    log_validator = jsonschema_rs.validator_for(FOXGLOVE_LOG)
    events = received.json("/events")
    for log_ns, doc in events:
        log_validator.validate(doc)
        assert doc["timestamp"]["sec"] * 10**9 + doc["timestamp"]["nsec"] == log_ns
    transitions = [
        (json.loads(d["message"].partition(": ")[2]), d["name"])
        for _, d in events
        if d["message"].startswith("pass_state: ")
    ]
    assert [(t["from"], t["to"], who) for t, who in transitions] == [
        ("scheduled", "aos", "otto"),
        ("aos", "running", "otto"),
        ("running", "los", "ground"),
        ("los", "complete", "ground"),
    ]

    # the URDF once (at least), the plan's hand path and the commanded arm on /scene
    [(_, description), *_] = received.json("/robot_description")
    assert description["data"].startswith("<?xml") or "<robot" in description["data"]
    scene = received.messages["/scene"]
    assert any(b"predicted_hand_path" in m for _, m in scene)
    assert sum(b"commanded_arm" in m for _, m in scene) > 10


def test_the_gate_asks_a_viewers_token_and_a_foxglove_subprotocol(tmp_path: Path) -> None:
    """401 without a token or with an unknown one, 403 for the spacecraft's, 400 for a client
    that offers neither subprotocol; a token in the URL (the Foxglove app's only way) with the
    protocol's first name is let in and hears the SDK's serverInfo."""
    pytest.importorskip("foxglove", reason="the foxglove extra (hikoboshi[foxglove])")
    from websockets.asyncio.client import connect
    from websockets.exceptions import InvalidStatus

    async def refused(url: str, **kwargs: object) -> tuple[int, str]:
        with pytest.raises(InvalidStatus) as caught:
            async with connect(url, **kwargs):  # type: ignore[arg-type]
                pass
        response = caught.value.response
        return response.status_code, response.body.decode() if response.body else ""

    async def scenario(url: str) -> None:
        v1 = ["foxglove.websocket.v1"]
        status, body = await refused(url, subprotocols=v1)
        assert status == 401 and "viewer's token is required" in body
        status, body = await refused(f"{url}/?token=guess", subprotocols=v1)
        assert status == 401 and "unknown token (given in the url)" in body
        spacecraft_token = {"Authorization": "Bearer s-token"}
        status, body = await refused(url, subprotocols=v1, additional_headers=spacecraft_token)
        assert status == 403 and "'spacecraft' may not watch" in body
        status, _ = await refused(url, subprotocols=["ros1"], additional_headers=VIEWER)
        assert status == 400
        async with connect(f"{url}/?token=v-token", subprotocols=v1) as ws:  # type: ignore[list-item]
            assert ws.subprotocol == "foxglove.websocket.v1"
            hello = json.loads(await asyncio.wait_for(ws.recv(), 10.0))  # a guard
            assert hello["op"] == "serverInfo" and hello["name"] == "hikoboshi"

    with running_ground(sqlite_url(tmp_path), foxglove_port=0) as ground:
        gate = ground.app.state.foxglove_gate
        asyncio.run(scenario(f"ws://127.0.0.1:{gate.port}"))
        assert gate.connections == 1


def test_without_the_extra_the_port_is_refused_with_one_line(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "foxglove", None)  # import foxglove: ImportError
    monkeypatch.setenv("HIKOBOSHI_DATA_DIR", str(tmp_path))
    for argv in (
        ["serve", "--foxglove-port", "8765"],
        ["demo", "--out", str(tmp_path / "demo"), "--foxglove-port", "8765"],
    ):
        result = CliRunner().invoke(app, argv)
        assert result.exit_code == 2, result.output
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "hikoboshi[foxglove]" in lines[0], lines
    monkeypatch.setenv("HIKOBOSHI_FOXGLOVE_PORT", "8765")  # the setting alone, too
    result = CliRunner().invoke(app, ["serve"])
    assert result.exit_code == 2 and "hikoboshi[foxglove]" in result.stderr
