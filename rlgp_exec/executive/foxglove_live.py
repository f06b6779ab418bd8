"""``run --foxglove [PORT]``: the running executive served live to Foxglove over its WebSocket protocol.

:class:`FoxgloveLive` takes the executive's records as a recorder does and serves what a recording's
viewer channels hold (:mod:`~rlgp_exec.executive.ros_record`: the URDF, TF, joint states, odometry,
the scene's and the plan's entities, the head camera's images when the camera is in the loop), from the
same message builders, through foxglove-sdk's server (connect Foxglove to ``ws://HOST:PORT``). The
messages a client needs however late it connects (the URDF, static TF, the scene and the plan) are sent
again every ``LATCH_S``.

:class:`Tee` hands each record to several sinks (a recording and the live view).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any

import foxglove

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive import ros_messages as rm
from rlgp_exec.executive.recorder import CAMERA_TYPES, RecordSink
from rlgp_exec.executive.ros_record import ROS_CHANNELS, RosView

__all__ = ["CLIENT_POLLER_LOGGER", "DEFAULT_PORT", "LATCH_S", "ClientDropAtInfo", "FoxgloveLive", "Tee"]

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765  # Foxglove's default for a WebSocket connection
LATCH_S = 1.0  # [s] the latched channels are sent again this often
LATCHED = ("/robot_description", "/tf_static", "/scene_entities", "/plan_path")
STATE_VIEW_S = 0.02  # [s] robot states closer than this to the last one are not sent (50 Hz)
#: the SDK's logger (its Rust ``log`` records, bridged to Python logging) for a client's receive errors
CLIENT_POLLER_LOGGER = "foxglove.websocket.connected_client.poller"
#: what a receive error says when the client just went away (a closed tab, a dropped network link)
CLIENT_DROPS = ("Connection reset", "Broken pipe", "without closing handshake", "Connection aborted")


class ClientDropAtInfo(logging.Filter):
    """The SDK's ERROR for a viewer that went away without a close frame ("Error receiving from client ...:
    IO error: Connection reset by peer"), as the INFO event it is: a viewer leaving never harms the run.
    Other errors of the logger stay errors."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno >= logging.ERROR:
            msg = record.getMessage()
            if msg.startswith("Error receiving from client") and any(d in msg for d in CLIENT_DROPS):
                record.levelno, record.levelname = logging.INFO, "INFO"
                return logging.getLogger(record.name).isEnabledFor(logging.INFO)
        return True


class FoxgloveLive:
    """A foxglove-sdk WebSocket server on ``host:port`` (0: a free port, see ``port``) fed by ``write``."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1") -> None:
        if not 0 <= port <= 65535:
            raise RlgpError(f"--foxglove {port}: a TCP port is 0..65535")
        self.on_error: Callable[[str], None] | None = None  # (a RecordSink; serving never fails a task)
        self._context = foxglove.Context()
        self._drop_filter = ClientDropAtInfo()
        logging.getLogger(CLIENT_POLLER_LOGGER).addFilter(self._drop_filter)
        try:
            self._server = foxglove.start_server(name="rlgp-exec", host=host, port=port, context=self._context)
        except Exception as e:  # the SDK raises its own error types for a busy or bad address
            logging.getLogger(CLIENT_POLLER_LOGGER).removeFilter(self._drop_filter)
            raise RlgpError(f"--foxglove: cannot serve on {host}:{port}: {e}") from e
        self.port = self._server.port
        self.channels = {
            ch.topic: foxglove.Channel(
                ch.topic,
                message_encoding=ch.message_encoding,
                schema=foxglove.Schema(name=ch.schema_name, encoding=ch.schema_encoding, data=ch.schema_data),
                context=self._context,
            )
            for ch in ROS_CHANNELS.values()
        }
        self._view = RosView()
        self._lock = threading.Lock()
        self._latched: dict[tuple[str, str], bytes] = {}  # (channel, record topic): the last payload
        self._failed: set[str] = set()
        self._last_state = -math.inf
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._relatch, name="foxglove-latch", daemon=True)
        self._thread.start()
        log.info("foxglove: serving on ws://%s:%d", host, self.port)

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    def write(self, topic: str, data: dict[str, Any], t_wall: float | None = None) -> None:
        """Serve the viewer's messages of the record ``data`` on ``topic`` (never raises for bad data)."""
        t = time.time() if t_wall is None else t_wall
        with self._lock:
            if self._stop.is_set():
                return
            if topic == "/robot_state":
                if t - self._last_state < STATE_VIEW_S:
                    return
                self._last_state = t
            try:
                out = self._view.derive(topic, data, t)
            except Exception as e:  # a record it cannot draw is logged once and the task goes on
                if topic not in self._failed:
                    self._failed.add(topic)
                    log.warning("foxglove: nothing to show for a %s record: %s: %s", topic, type(e).__name__, e)
                return
            for channel, payload in out:
                if channel in LATCHED:  # the scene's entities, and the drawers moved since, each kept
                    self._latched[(channel, topic)] = payload
                self.channels[channel].log(payload, log_time=int(t * 1e9))

    def write_ros(self, topic: str, typename: str, payload: bytes, t_wall: float) -> None:
        """Serve the CDR ``payload`` of ``typename`` (one of ``CAMERA_TYPES``) on ``topic``, its first message
        advertising the channel."""
        if typename not in CAMERA_TYPES or topic in ROS_CHANNELS:
            raise RlgpError(f"foxglove: {typename} on {topic!r}: only {list(CAMERA_TYPES)} on channels of their own")
        with self._lock:
            if self._stop.is_set():
                return
            channel = self.channels.get(topic)
            if channel is None:
                s = rm.ros_schema(typename)
                channel = self.channels[topic] = foxglove.Channel(
                    topic, message_encoding=s.message_encoding,
                    schema=foxglove.Schema(name=s.name, encoding=s.encoding, data=s.text.encode()),
                    context=self._context,
                )
            channel.log(payload, log_time=int(t_wall * 1e9))

    def _relatch(self) -> None:
        while not self._stop.wait(LATCH_S):
            with self._lock:
                now = int(time.time() * 1e9)
                for (channel, _), payload in self._latched.items():
                    self.channels[channel].log(payload, log_time=now)

    def close(self) -> None:
        with self._lock:
            if self._stop.is_set():
                return
            self._stop.set()
        self._thread.join(timeout=2 * LATCH_S)
        self._server.stop()
        logging.getLogger(CLIENT_POLLER_LOGGER).removeFilter(self._drop_filter)

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Tee:
    """Each record to every sink; ``on_error`` is handed on to them (the recording's failures)."""

    def __init__(self, *sinks: RecordSink) -> None:
        self.sinks = sinks

    @property
    def on_error(self) -> Callable[[str], None] | None:
        return self.sinks[0].on_error if self.sinks else None

    @on_error.setter
    def on_error(self, fn: Callable[[str], None] | None) -> None:
        for s in self.sinks:
            s.on_error = fn

    def write(self, topic: str, data: dict[str, Any], t_wall: float | None = None) -> None:
        t = time.time() if t_wall is None else t_wall  # one time for all: the same instant in each
        for s in self.sinks:
            s.write(topic, data, t)

    def write_ros(self, topic: str, typename: str, payload: bytes, t_wall: float) -> None:
        """A ROS 2 message to every sink that takes them (``write_ros``)."""
        for s in self.sinks:
            s.write_ros(topic, typename, payload, t_wall)
