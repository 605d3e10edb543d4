"""Crash-safe trial logs: one MCAP file per trial, JSON messages with JSON schemas.

The writer never chunks, and flushes and fsyncs after every message, so a ``kill -9`` at
any moment loses at most the message being written (with default settings
``mcap`` loses the whole file). ``finish()`` runs in ``finally`` and writes the summary;
a file without it is still read by :func:`read_trial`, which streams records and stops
cleanly at a truncated tail. The logs open in Foxglove (topics ``/pose``, ``/command``,
``/telemetry``, ``/event``, ``/decision``), and beside them, in Foxglove's well-known types
(:mod:`tumblebot.host.foxglove`), the robot's transform and pose for every ``/pose``, the
robot as a box with legs and the setpoint and start circle, so a trial plays back in 3D.
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: JSON schemas of the topics (Foxglove shows fields by these).
SCHEMAS: dict[str, dict[str, Any]] = {
    "/pose": {"type": "object", "title": "tumblebot.Pose", "properties": {
        "t": {"type": "number", "description": "host monotonic time, s"},
        "p": {"type": "array", "items": {"type": "number"}, "description": "lab-frame position x, y, z (m)"},
        "q": {"type": "array", "items": {"type": "number"}, "description": "orientation quaternion x, y, z, w"},
        "source_time": {"type": "number", "description": "the source's own timestamp, s (absent if it has none)"},
        "seq": {"type": "integer", "description": "the source's frame counter (absent if it has none)"}}},
    "/decision": {"type": "object", "title": "tumblebot.Decision", "properties": {
        "step": {"type": "integer"},
        "t": {"type": "number", "description": "host monotonic time the command left, s (the clock of /pose t)"},
        "observation": {"type": "array", "items": {"type": "number"}},
        "command": {"type": "array", "items": {"type": "integer"}}, "distance": {"type": "number"},
        "latency_ms": {"type": "number"}}},
    "/command": {"type": "object", "title": "tumblebot.Command", "properties": {
        "right": {"type": "integer"}, "left": {"type": "integer"}, "kind": {"type": "string"}}},
    "/telemetry": {"type": "object", "title": "tumblebot.Telemetry", "properties": {}},
    "/event": {"type": "object", "title": "tumblebot.Event", "properties": {
        "event": {"type": "string"}, "detail": {"type": "string"}}},
}


def topic_schemas() -> dict[str, dict[str, Any]]:
    """Every topic a trial log carries → its JSON schema: ours and Foxglove's well-known types."""
    from tumblebot.host import foxglove

    return {**SCHEMAS, **foxglove.SCHEMAS}


class TrialLogWriter:
    """Appends messages to one trial's MCAP file; every ``write`` is on disk when it returns."""

    def __init__(self, path: Path, metadata: dict[str, str] | None = None,
                 on_written: Callable[[int], None] | None = None,
                 mirror: Callable[[str, bytes, int], None] | None = None) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = path
        self.on_written = on_written  #: called with each message's sequence number once it is on disk
        #: called with (topic, JSON payload, log time in ns) of every message written, after it
        #: is written: a live view (:class:`tumblebot.host.live.LiveView`'s ``publish``)
        self.mirror = mirror
        self._file = path.open("wb")
        self._writer = Writer(self._file, use_chunking=False, compression=CompressionType.NONE,
                              use_statistics=True, use_summary_offsets=True)
        self._writer.start(profile="", library="tumblebot")
        self._channels: dict[str, int] = {}
        self._seq = 0
        self._finished = False
        for topic, schema in topic_schemas().items():
            sid = self._writer.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(topic, "json", sid)
        if metadata:
            self._writer.add_metadata("trial", {k: str(v) for k, v in metadata.items()})
            self._write_scene(metadata)
        self._sync()

    def _write_scene(self, metadata: dict[str, str]) -> None:
        """The robot model and the setpoint markers, when the metadata has the design and setpoint."""
        from tumblebot.host import foxglove

        now = time.time()
        try:
            design = tuple(float(v) for v in json.loads(metadata["design"]))
            setpoint = tuple(float(v) for v in json.loads(metadata["setpoint"]))
            start = tuple(float(v) for v in json.loads(metadata["start"])) if "start" in metadata else None
            radius = float(metadata["radius"]) if "radius" in metadata else None
        except (KeyError, ValueError, TypeError):
            return  # a log without a known design (tests, tools): our own topics only
        if len(design) == 4 and len(setpoint) == 2:
            self._add("/robot/model", foxglove.robot_model(now, design), now)
            self._add("/scene", foxglove.scene(now, setpoint, radius,
                                               start if start is not None and len(start) == 2 else None), now)

    def _add(self, topic: str, data: dict[str, Any], t: float) -> int:
        ns = int(t * 1e9)
        self._seq += 1
        payload = json.dumps(data, separators=(",", ":")).encode()
        self._writer.add_message(self._channels[topic], log_time=ns, publish_time=ns, sequence=self._seq,
                                 data=payload)
        if self.mirror is not None:
            self.mirror(topic, payload, ns)
        return self._seq

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())

    def write(self, topic: str, data: dict[str, Any], t: float | None = None) -> int:
        """Log one message (``t``: wall-clock s, default now). Returns its sequence number.

        A ``/pose`` also writes its Foxglove ``/tf`` and ``/robot/pose`` (the next sequence
        numbers), in the same fsync."""
        from tumblebot.host import foxglove

        if self._finished:
            raise ValueError(f"trial log {self.path} is finished")
        when = time.time() if t is None else t
        seq = self._add(topic, data, when)
        if topic == "/pose" and len(data.get("p", ())) == 3 and len(data.get("q", ())) == 4:
            for derived, message in foxglove.pose_messages(when, data["p"], data["q"]).items():
                self._add(derived, message, when)
        self._sync()
        if self.on_written is not None:
            self.on_written(seq)
        return seq

    def finish(self) -> None:
        if self._finished:
            return
        self._finished = True
        try:
            self._writer.finish()  # type: ignore[no-untyped-call]
            self._sync()
        finally:
            self._file.close()

    def __enter__(self) -> TrialLogWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.finish()


class BackgroundLog:
    """Hands messages to a :class:`TrialLogWriter` running in its own thread.

    The controller must never wait for a disk: with the writer's fsync per message in the
    control loop, a frame arriving during an fsync waited for it (p50 2.3 ms instead of
    0.4 ms, ``benchmarks/bench_host.py``). A message counts as written when the writer
    thread's ``write`` returned (that is when ``on_written`` fires); ``close()`` drains
    the queue. An error in the writer thread is raised by the next ``write`` or ``close``.
    """

    def __init__(self, writer: TrialLogWriter) -> None:
        self.writer = writer
        self._queue: queue.SimpleQueue[tuple[str, dict[str, Any], float] | None] = queue.SimpleQueue()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True, name=f"log {writer.path.name}")
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                self.writer.write(*item)
            except BaseException as exc:  # surfaced to the controller's thread
                self._error = exc
                return

    def write(self, topic: str, data: dict[str, Any], t: float | None = None) -> None:
        if self._error is not None:
            raise self._error
        self._queue.put((topic, data, time.time() if t is None else t))

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join()
        if self._error is not None:
            raise self._error


@dataclass
class LogMessage:
    topic: str
    log_time: float  #: wall-clock s
    sequence: int
    data: dict[str, Any]


@dataclass
class TrialLog:
    path: Path
    messages: list[LogMessage] = field(default_factory=list)
    metadata: dict[str, str] = field(default_factory=dict)
    complete: bool = False  #: the file ends with its footer (finish() ran)

    def topic(self, name: str) -> list[LogMessage]:
        return [m for m in self.messages if m.topic == name]


def read_trial(path: Path) -> TrialLog:
    """Every message of a trial log, streaming, so a truncated file still reads."""
    from mcap.records import Channel, DataEnd, Footer, Message, Metadata
    from mcap.stream_reader import StreamReader

    log = TrialLog(path)
    channels: dict[int, str] = {}
    with path.open("rb") as fh:
        reader = StreamReader(fh, skip_magic=False)
        try:
            for record in reader.records:
                if isinstance(record, Channel):
                    channels[record.id] = record.topic
                elif isinstance(record, Message):
                    try:
                        data = json.loads(record.data)
                    except json.JSONDecodeError:
                        break
                    log.messages.append(LogMessage(channels.get(record.channel_id, "?"), record.log_time / 1e9,
                                                   record.sequence, data))
                elif isinstance(record, Metadata):
                    log.metadata.update(record.metadata)
                elif isinstance(record, DataEnd | Footer):
                    log.complete = True
        except Exception:  # a truncated tail (kill -9 mid-record): everything before it is kept
            pass
    return log


def write_json_atomic(path: Path, data: Any) -> None:
    """Replace ``path`` with ``data`` as JSON, atomically (write, fsync, rename, fsync dir)."""
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w") as fh:
        json.dump(data, fh, indent=2)
        fh.write("\n")
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
