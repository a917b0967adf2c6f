"""Foxglove live: the pass as it flies, on foxglove-sdk's websocket server in the ground process.

Optional (the ``hikoboshi[foxglove]`` extra): :func:`foxglove_missing` says why it cannot
start, and nothing here imports ``foxglove`` before :meth:`FoxgloveLive.start`.

The channels are the MCAP recording's, with its schemas and JSON encoding
(``telemetry.mcap``, docs/mcap.md), so one Foxglove layout serves a file and a live pass:

- ``/tf`` (``foxglove.FrameTransforms``) and ``/plot/joints``, ``/plot/base``,
  ``/plot/wheels``: one message per archived telemetry frame, log time its generation time;
- ``/robot_description`` (the URDF) and ``/plot/prediction``: once per pass, at its first
  frame, and again to every client that subscribes later;
- ``/events`` (``foxglove.Log``): every committed audit event, log time its ground time;
- ``/scene`` (``foxglove.SceneUpdate``, the SDK's own schema): the plan's predicted hand path
  (a line strip in the ``orbit`` frame) and the commanded arm (a line strip through the link
  origins at the commanded joint angles, with a sphere at the hand, in ``base_link``).

It never slows ingest: the publisher's callbacks (on the event loop, after each commit) only
append to a bounded queue and wake one thread, which makes and sends the messages (and makes
none while no client is connected). The thread works at most :data:`MAX_DUTY` of the time
and sleeps the rest, so under a flood of telemetry it falls behind rather than taking the
GIL from ingest. When that
thread falls behind, the oldest queued item goes and :attr:`FoxgloveLive.dropped` counts it.
bench/bench_foxglove.py measures the cost on the ingest path as a ratio.
"""

from __future__ import annotations

import collections
import json
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlalchemy.orm import Session, sessionmaker

from planner.model import RobotModel, default_model
from planner.plan import Plan
from planner.urdf import urdf_xml
from server.services.dbworker import Publisher
from server.services.errors import ConflictError
from server.services.event_log import Recorded
from server.services.robots import model_for_plan, urdf_for_plan
from server.storage import repository as repo
from telemetry.foxglove import (
    FRAME_TRANSFORMS_SCHEMA,
    LOG_SCHEMA,
    ORBIT_FRAME,
    STRING_SCHEMA,
    FrameTransformer,
    event_log,
)
from telemetry.mcap import TOPIC_EVENT_LOG, TOPIC_ROBOT_DESCRIPTION, TOPIC_TF
from telemetry.mcap._plots import (
    TOPIC_PLOT_PREDICTION,
    frame_plot_messages,
    prediction_plot_messages,
)
from telemetry.recording import frames_to_arrays
from telemetry.wire import TelemetryFrame

__all__ = [
    "EXTRA",
    "MAX_DUTY",
    "QUEUE_ITEMS",
    "TOPIC_SCENE",
    "FoxgloveLive",
    "FoxgloveUnavailable",
    "foxglove_missing",
]

log = logging.getLogger("hikoboshi.ground.foxglove")

#: What to install for the live view.
EXTRA = "hikoboshi[foxglove]"
TOPIC_SCENE = "/scene"
#: Queued items (a telemetry message's frames, or one event) before the oldest is dropped:
#: 256 messages of frames are a minute of telemetry at 4 Hz.
QUEUE_ITEMS = 256
#: The share of the time the view's thread may work (it sleeps the rest): the bound on
#: what it takes from ingest when telemetry comes faster than it can follow.
MAX_DUTY = 0.2
#: Messages the SDK's server buffers for each client before it drops the oldest (its default
#: is 1,024: a frame is five messages, /tf and the plots, so a client that stalled for a few
#: seconds while a minute of backlog was sent lost /tf messages in the suite on a busy
#: machine). A minute of 4 Hz telemetry at 10x is 12,000 messages, a few MB per client.
CLIENT_BACKLOG = 16384
_SCENE_PATH = "predicted_hand_path"
_SCENE_ARM = "commanded_arm"
#: The chain the commanded arm is drawn through (links the model lacks are skipped).
_ARM_CHAIN = ("robot_base", "link1", "link2", "link3", "link4", "link5", "link6", "hand")


class FoxgloveUnavailable(RuntimeError):
    """The live view was asked for and the extra is not installed (or the port is taken)."""


def foxglove_missing() -> str | None:
    """Why the live view cannot run here (one line naming the extra), or None."""
    try:
        import foxglove  # noqa: F401  (the native library loads: the check is real)
    except ImportError:
        return (
            f"the Foxglove live view needs the {EXTRA} extra (foxglove-sdk): pip install '{EXTRA}'"
        )
    return None


@dataclass
class _PassView:
    """What one pass's messages are made from (read once, at its first frame)."""

    pass_id: str
    plan: Plan
    epoch_ns: int
    transformer: FrameTransformer
    static: list[tuple[str, bytes, int]]  # (topic, message, log time): sent again on subscribe


class FoxgloveLive:
    """foxglove-sdk's websocket server on ``host:port`` (0: a free port, :attr:`port`),
    fed from ``publisher``; ``sessions`` reads a pass's plan; ``robot_files`` as the
    server's setting (a plan's robot model, :func:`server.services.robots.model_for_plan`)."""

    def __init__(
        self,
        *,
        host: str,
        port: int,
        publisher: Publisher,
        sessions: sessionmaker[Session],
        robot_files: Sequence[str] = (),
        queue_items: int = QUEUE_ITEMS,
    ) -> None:
        self._host, self._port = host, port
        self._publisher = publisher
        self._sessions = sessions
        self._robot_files = tuple(robot_files)
        self._queue: collections.deque[tuple[str, Any]] = collections.deque()
        self._queue_items = queue_items
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = False
        self._busy = False
        self._thread: threading.Thread | None = None
        self._unsubscribe: list[Callable[[], None]] = []
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}
        self._schemas: dict[str, bytes] = {}
        self._scene: Any = None
        self._views: dict[str, _PassView] = {}
        self._current: _PassView | None = None
        self._unviewable: set[str] = set()
        #: items dropped because the thread was behind, and messages sent
        self.dropped = 0
        self.sent = 0

    @property
    def port(self) -> int:
        return int(self._server.port) if self._server is not None else self._port

    # -- lifecycle -----------------------------------------------------------------------

    def start(self) -> None:
        """Listen, make the channels and subscribe to the publisher (:class:`FoxgloveUnavailable`
        without the extra or when the port cannot be bound)."""
        missing = foxglove_missing()
        if missing is not None:
            raise FoxgloveUnavailable(missing)
        import foxglove
        from foxglove.channels import SceneUpdateChannel
        from foxglove.websocket import ChannelView, Client, ServerListener

        live = self

        class Listener(ServerListener):
            """A subscription asks for the once-only messages again (a client that joins
            mid-pass gets the URDF, the prediction and the hand path)."""

            def on_subscribe(self, client: Client, channel: ChannelView) -> None:
                if channel.topic in (TOPIC_ROBOT_DESCRIPTION, TOPIC_SCENE, TOPIC_PLOT_PREDICTION):
                    live.resend_static()

        context = foxglove.Context()  # ours alone: nothing else logs to this server
        listener = Listener()
        try:
            self._server = foxglove.start_server(
                name="hikoboshi",
                host=self._host,
                port=self._port,
                context=context,
                server_listener=listener,
                message_backlog_size=CLIENT_BACKLOG,
            )
        except Exception as exc:  # the SDK raises its own error for a port in use
            raise FoxgloveUnavailable(
                f"the Foxglove server cannot listen on {self._host}:{self._port}: {exc}"
            ) from exc

        self._context = context
        self._channel(TOPIC_TF, FRAME_TRANSFORMS_SCHEMA, "onboard")
        self._channel(TOPIC_ROBOT_DESCRIPTION, STRING_SCHEMA, "onboard")
        self._channel(TOPIC_EVENT_LOG, LOG_SCHEMA, "ground")
        self._scene = SceneUpdateChannel(TOPIC_SCENE, context=context)
        self._thread = threading.Thread(target=self._run, name="foxglove", daemon=True)
        self._thread.start()
        self._unsubscribe = [
            self._publisher.subscribe_frames(self._on_frames),
            self._publisher.subscribe(self._on_event),
        ]
        log.info("Foxglove live view on ws://%s:%d", self._host, self.port)

    def close(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe = []
        self._stop = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
        if self._server is not None:
            self._server.stop()
            self._server = None

    # -- the hot path's side: append and wake --------------------------------------------

    def _put(self, item: tuple[str, Any]) -> None:
        with self._lock:
            if len(self._queue) >= self._queue_items:
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(item)
        self._wake.set()

    def _on_frames(self, pass_id: str, frames: list[TelemetryFrame], reception_ns: int) -> None:
        self._put(("frames", (pass_id, frames)))

    def _on_event(self, recorded: Recorded) -> None:
        self._put(("event", recorded))

    def resend_static(self) -> None:
        """A client subscribed: the current pass's once-only messages go out again."""
        self._put(("static", None))

    # -- the thread ----------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            self._wake.wait()
            with self._lock:
                items = list(self._queue)
                self._queue.clear()
                self._wake.clear()
                self._busy = True
            if self._stop:
                return
            started = time.perf_counter()
            try:
                self._handle(items)
            finally:
                self._busy = False
            # At most MAX_DUTY of one core (and of the GIL) for the view: rest in proportion
            # to the work done; what comes meanwhile queues, and the oldest goes.
            worked = time.perf_counter() - started
            if not self._stop:
                time.sleep(worked * (1.0 / MAX_DUTY - 1.0))

    def idle(self) -> bool:
        """Nothing queued and nothing being made (for a bench or a test to wait on)."""
        with self._lock:
            return not self._queue and not self._busy

    def _handle(self, items: list[tuple[str, Any]]) -> None:
        for kind, payload in items:
            try:
                if kind == "frames":
                    self._frames(*payload)
                elif kind == "event":
                    self._event(payload)
                elif self._current is not None:
                    self._send_static(self._current)
            except Exception:
                log.exception("Foxglove live view: %s not sent", kind)

    def _log(self, topic: str, data: bytes, log_ns: int) -> None:
        self._channels[topic].log(data, log_time=log_ns)
        self.sent += 1

    def _event(self, recorded: Recorded) -> None:
        r = recorded
        message = event_log(r.time_ns, r.kind, r.actor, r.event.detail())
        self._log(TOPIC_EVENT_LOG, json.dumps(message).encode(), r.time_ns)

    def _view(self, pass_id: str) -> _PassView | None:
        view = self._views.get(pass_id)
        if view is not None:
            return view
        with self._sessions() as session:
            record = repo.get_pass(session=session, pass_id=pass_id)
            if record.epoch_ns is None:
                return None
            plan = Plan.from_json(repo.get_plan(session=session, plan_id=record.plan_id).document)
            epoch_ns = int(record.epoch_ns)
        try:
            model: RobotModel = model_for_plan(plan, self._robot_files) or default_model()
            urdf = urdf_for_plan(plan, self._robot_files) or urdf_xml(model, name=plan.robot)
        except ConflictError as exc:  # a robot this server has no description of
            if pass_id not in self._unviewable:
                log.warning("Foxglove live view: pass %s not shown: %s", pass_id, exc)
            self._unviewable.add(pass_id)
            return None
        pred_schema, pred_ns, pred = prediction_plot_messages(plan, epoch_ns)
        self._channel(TOPIC_PLOT_PREDICTION, pred_schema, "onboard")
        static = [(TOPIC_ROBOT_DESCRIPTION, json.dumps({"data": urdf}).encode(), epoch_ns)]
        static += [
            (TOPIC_PLOT_PREDICTION, data, t) for t, data in zip(pred_ns.tolist(), pred, strict=True)
        ]
        view = _PassView(pass_id, plan, epoch_ns, FrameTransformer(model, urdf), static)
        self._views = {pass_id: view}  # one pass flies at a time
        return view

    def _channel(self, topic: str, schema: dict[str, Any], clock: str) -> None:
        """Make ``topic``'s channel, or make it again for another schema (a robot of another
        joint count has other plot fields)."""
        import foxglove

        data = json.dumps(schema, separators=(",", ":")).encode()
        old = self._channels.get(topic)
        if old is not None:
            if self._schemas.get(topic) == data:
                return
            old.close()
        self._channels[topic] = foxglove.Channel(
            topic,
            schema=foxglove.Schema(name=schema["title"], encoding="jsonschema", data=data),
            message_encoding="json",
            context=self._context,
            metadata={"clock": clock},
        )
        self._schemas[topic] = data

    def _send_static(self, view: _PassView) -> None:
        for topic, data, log_ns in view.static:
            self._log(topic, data, log_ns)
        self._scene_path(view)

    def _frames(self, pass_id: str, frames: list[TelemetryFrame]) -> None:
        if not any(channel.has_sinks() for channel in (*self._channels.values(), self._scene)):
            return  # no client listening: nothing to make (a subscription resends the rest)
        view = self._view(pass_id)
        if view is None:
            return
        if self._current is not view:
            self._current = view
            self._send_static(view)
        arrays = frames_to_arrays(frames)
        gen_ns = arrays.generation_time_ns
        tf = view.transformer(gen_ns, arrays.quat_orbit_from_base_xyzw, arrays.joints_rad)
        for t, data in zip(gen_ns.tolist(), tf, strict=True):
            self._log(TOPIC_TF, data, t)
        t_s = (gen_ns - view.epoch_ns).astype(np.float64) / 1e9
        for topic, (schema, log_ns, messages) in frame_plot_messages(arrays, t_s).items():
            self._channel(topic, schema, "onboard")
            for t, data in zip(log_ns.tolist(), messages, strict=True):
                self._log(topic, data, t)
        self._scene_arm(view, arrays.joint_targets_rad[-1], int(gen_ns[-1]))

    # -- scene ---------------------------------------------------------------------------

    def _scene_path(self, view: _PassView) -> None:
        from foxglove.messages import (
            Color,
            LinePrimitive,
            LinePrimitiveLineType,
            Point3,
            SceneEntity,
            SceneUpdate,
            Timestamp,
        )

        hand = np.asarray(view.plan.prediction.hand_pos_orbit_m, dtype=np.float64).reshape(-1, 3)
        sec, nsec = divmod(view.epoch_ns, 1_000_000_000)
        line = LinePrimitive(
            type=LinePrimitiveLineType.LineStrip,
            thickness=2.0,
            scale_invariant=True,
            points=[Point3(x=x, y=y, z=z) for x, y, z in hand.tolist()],
            color=Color(r=0.2, g=0.6, b=1.0, a=1.0),
        )
        entity = SceneEntity(
            timestamp=Timestamp(sec, nsec),
            frame_id=ORBIT_FRAME,
            id=_SCENE_PATH,
            frame_locked=True,
            lines=[line],
        )
        self._scene.log(SceneUpdate(entities=[entity]), log_time=view.epoch_ns)
        self.sent += 1

    def _scene_arm(self, view: _PassView, joint_targets_rad: Any, log_ns: int) -> None:
        from foxglove.messages import (
            Color,
            LinePrimitive,
            LinePrimitiveLineType,
            Point3,
            Pose,
            Quaternion,
            SceneEntity,
            SceneUpdate,
            SpherePrimitive,
            Timestamp,
            Vector3,
        )

        poses = view.transformer.link_poses(np.asarray(joint_targets_rad, dtype=np.float64))
        points = [poses[name][0][0].tolist() for name in _ARM_CHAIN if name in poses]
        orange = Color(r=1.0, g=0.55, b=0.0, a=0.9)
        hand = points[-1]
        entity = SceneEntity(
            timestamp=Timestamp(*divmod(log_ns, 1_000_000_000)),
            frame_id="base_link",
            id=_SCENE_ARM,
            frame_locked=True,
            lines=[
                LinePrimitive(
                    type=LinePrimitiveLineType.LineStrip,
                    thickness=4.0,
                    scale_invariant=True,
                    points=[Point3(x=x, y=y, z=z) for x, y, z in points],
                    color=orange,
                )
            ],
            spheres=[
                SpherePrimitive(
                    pose=Pose(
                        position=Vector3(x=hand[0], y=hand[1], z=hand[2]),
                        orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                    ),
                    size=Vector3(x=0.08, y=0.08, z=0.08),
                    color=orange,
                )
            ],
        )
        self._scene.log(SceneUpdate(entities=[entity]), log_time=log_ns)
        self.sent += 1
