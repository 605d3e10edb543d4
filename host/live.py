"""A live view of trials in Foxglove: the trial log's messages, streamed as they are written.

``tumblebot trial run --foxglove [HOST:]PORT`` (and ``twin run --foxglove``) starts a
Foxglove WebSocket server (``foxglove-sdk``, in the ``host`` extra) and sends it every
message the trial log writes, on the same topics, schemas and timestamps: open Foxglove,
"Open connection" → ``ws://HOST:PORT`` (and the layout ``docs/foxglove-layout.json``)
and the robot moves in 3D while the trial runs. The log on disk stays the record; the
stream is a view, and a viewer that connects, drops or lags never slows the controller
(the SDK queues and drops per client).

The robot model and the scene (setpoint, start circle) are written once per trial, so
they are kept and sent again to each viewer that subscribes later.

The server listens on loopback unless told otherwise: anyone who can reach the port sees
the trial (positions, commands) and nothing more; it accepts no input (no client
publishing, services or parameters are enabled).
"""

from __future__ import annotations

import json
import threading
from typing import Any

from tumblebot.errors import TumblebotError

#: Topics whose last message a viewer needs whenever it subscribes (written once a trial).
LATCHED = ("/robot/model", "/scene")
DEFAULT_HOST = "127.0.0.1"


def parse_listen(text: str) -> tuple[str, int]:
    """``PORT`` or ``HOST:PORT`` (port 0: any free port) → ``(host, port)``; loopback by default."""
    host, _, port_text = text.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535 or (":" in text and not host):
        raise TumblebotError(f"--foxglove {text!r}: expected PORT or HOST:PORT (port 0–65535), e.g. 8765")
    return host or DEFAULT_HOST, port


def _import_sdk() -> Any:
    try:
        import foxglove
    except ImportError as exc:
        raise TumblebotError("--foxglove needs foxglove-sdk, in the host extra: "
                             "pip install 'tumblebot[host]'") from exc
    return foxglove


class LiveView:
    """A Foxglove WebSocket server carrying the trial log's topics.

    :meth:`publish` takes what :class:`~tumblebot.host.triallog.TrialLogWriter` writes
    (topic, the JSON payload, nanoseconds); pass ``live.publish`` as the writer's
    ``mirror``. :meth:`close` stops the server."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = 8765, name: str = "tumblebot") -> None:
        foxglove = _import_sdk()
        from tumblebot.host.triallog import topic_schemas

        self._context = foxglove.Context()  # our own channels, not the SDK's global ones
        self._lock = threading.Lock()
        self._latched: dict[str, tuple[bytes, int]] = {}
        self._channels: dict[str, Any] = {}
        for topic, schema in topic_schemas().items():
            self._channels[topic] = foxglove.Channel(
                topic, message_encoding="json", context=self._context,
                schema=foxglove.Schema(name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode()))
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context,
                                                 server_listener=_resend_listener(self))
        except Exception as exc:  # the SDK raises its own error types for a port in use or a bad address
            raise TumblebotError(f"--foxglove: cannot listen on {host}:{port}: {exc}") from exc
        self.host = host
        self.port = int(self._server.port)

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def publish(self, topic: str, payload: bytes, log_time_ns: int) -> None:
        """Send one message to every viewer subscribed to ``topic`` (unknown topics are ignored)."""
        channel = self._channels.get(topic)
        if channel is None:
            return
        if topic in LATCHED:
            with self._lock:
                self._latched[topic] = (payload, log_time_ns)
        channel.log(payload, log_time=log_time_ns)

    def resend(self, topic: str) -> None:
        """Send the latched message of ``topic`` again (a viewer has just subscribed)."""
        with self._lock:
            latched = self._latched.get(topic)
        if latched is not None:
            self._channels[topic].log(latched[0], log_time=latched[1])

    def close(self) -> None:
        self._server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _resend_listener(view: LiveView) -> Any:
    from foxglove.websocket import ServerListener  # present: LiveView imported the SDK first

    class Resend(ServerListener):
        """Sends a late subscriber the robot model and the scene."""

        def on_subscribe(self, client: Any, channel: Any) -> None:
            if channel.topic in LATCHED:
                view.resend(channel.topic)

    return Resend()

