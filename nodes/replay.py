"""The ``replay`` node: publishes a bag's topics in place of the nodes that recorded them.

Ports:
    inputs: none (a source).
    outputs: one per selected bag topic, named by the full topic (``left_camera/image``), so
        the graph's references to ``left_camera/image`` resolve to this node. The message
        type of each is the bag's schema, which must decode as today's declaration: the
        same fingerprint, or an older declaration that today's only extends with fields
        that have defaults (``messages.evolution``). A topic whose type changed otherwise
        is refused with an error naming the file, the topic, the offset, the type and the
        field (leave it out with ``topics``).

Frames are published verbatim, as recorded (``header.seq`` and ``stamp_nanos`` included),
so downstream nodes that use message stamps behave exactly as they did live; a message of
an older declaration goes out re-encoded as today's type, its new fields at their
defaults. Pacing:

- ``rate`` (default 1.0): the recorded receive times, scaled (2.0 = twice as fast);
- ``fast``: as fast as the graph takes them: at most ``window`` (256) messages in flight,
  then wait for the graph to be idle, so no queue overflows at its high-water mark (0 =
  unbounded; needs the launcher's idle tracking, which ``launch.py replay`` turns on);
- ``lockstep``: the same bag through the same nodes gives the same outputs whatever the
  load; implies ``fast`` pacing. Before a message that can reach a node merging several
  publishers (``io.lockstep_barrier``), wait until every node downstream has handled every
  message published so far (``io.wait_idle``); other messages go out without waiting (each
  node reads a publisher in its publishing order), at most ``window`` before an idle wait.
  The launcher must run the graph with ``lockstep=True`` for the runtime to track idleness.

``start_secs``/``end_secs`` cut the bag (seconds from its first message), ``topics`` selects
topics (a regex, ``re.search`` like ``launch.py --record-topics``), ``remap`` renames them (``{bag_topic: published_topic}``), and
``loop`` starts over at the end. When done (and not looping) the node waits for the graph
to drain and asks it to stop.

Each message is decoded (into its declared type) before it goes out: one that cannot be
is skipped, counted and logged (the first few, with file, topic and offset), and the
replay goes on; ``strict`` stops the node at the first instead. Chunks too damaged to
read are skipped by the bag reader, and counted too.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Annotated, Any

from msgspec import Meta

from messages.base import Message
from messages.codec import decode, encode
from messages.errors import BagError, FrameDecodeError, NodeError, SchemaChangeError
from runtime.bag import BagMessage, BagReader, topic_filter
from runtime.node import Node
from runtime.registry import register
from runtime.replaygraph import ReplayOptions

_LOGGED_SKIPS = 5  # undecodable messages logged one by one; the rest are counted


class ReplayParams(ReplayOptions, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """What to replay and how fast (see the module docstring)."""

    path: str
    idle_timeout_secs: Annotated[float, Meta(gt=0)] = 60.0
    tick_secs: Annotated[float, Meta(gt=0)] = 0.001
    batch_secs: Annotated[float, Meta(gt=0)] = 0.02
    stop_when_done: bool = True
    window: Annotated[int, Meta(ge=0)] = 256

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.path:
            raise ValueError("path must name the bag file, got ''")
        topic_filter(self.topics)  # raises ValueError on a bad regex


def replay_topics(params: ReplayParams) -> dict[str, tuple[str, type[Message]]]:
    """``{published_topic: (bag_topic, message class)}`` for the selected topics.

    Raises:
        ValueError: the bag cannot be read, no topic is selected, two topics remap to one,
            or a selected topic's schema is not today's (the message names file, topic and
            the offset of the record that declared the channel).
    """
    try:
        with BagReader(params.path) as reader:
            reader.topics()  # a foreign bag without a summary: reads the chunks' channels
            channels = {c.topic: c for c in reader.channels.values()}
    except BagError as err:
        raise ValueError(str(err)) from err
    chosen = topic_filter(params.topics)
    out: dict[str, tuple[str, type[Message]]] = {}
    for topic, channel in sorted(channels.items()):
        if not chosen(topic):
            continue
        published = params.remap.get(topic, topic)
        try:
            cls = channel.schema.current_class()
        except SchemaChangeError as err:
            raise ValueError(
                f"{params.path}: topic {topic}: channel at offset {channel.offset}: {err}; "
                "the graph cannot accept it (leave the topic out with topics/--replay-topics, "
                "or read it with `bag echo`)"
            ) from err
        if published in out:
            raise ValueError(
                f"{params.path}: topics {out[published][0]!r} and {topic!r} both replay as {published!r}"
            )
        out[published] = (topic, cls)
    unknown = sorted(set(params.remap) - set(channels))
    if unknown:
        raise ValueError(f"{params.path}: remap names topics not in the bag: {unknown}")
    if not out:
        raise ValueError(
            f"{params.path}: topics {params.topics!r} selects none of {sorted(channels)}"
        )
    return out


@register("replay")
class Replay(Node):
    """Publishes a bag's topics (see the module docstring)."""

    Params = ReplayParams

    @classmethod
    def ports(cls, params: Any) -> tuple[dict[str, type[Message]], dict[str, type[Message]]]:
        return {}, {pub: kind for pub, (_, kind) in replay_topics(params).items()}

    def setup(self) -> None:
        p = self.params
        chosen = replay_topics(p)
        self.topic_map = {bag: pub for pub, (bag, _) in chosen.items()}
        self.kinds = {bag: kind for bag, kind in chosen.values()}
        self.skipped = 0
        self.reader = BagReader(p.path, warn=self.io.log.warning)
        first = self.reader.first_log_nanos() or 0
        self.start_nanos = first + int(p.start_secs * 1e9)
        self.end_nanos = None if p.end_secs is None else first + int(p.end_secs * 1e9)
        self.fast = p.fast or p.lockstep
        self.published = 0
        self._in_flight = 0
        self.passes = 0
        self.done = False
        self._restart()
        self.io.add_timer(p.tick_secs, self._tick)

    def _restart(self) -> None:
        self._iter: Iterator[BagMessage] = self.reader.messages(
            self.topic_map, start_nanos=self.start_nanos, end_nanos=self.end_nanos
        )
        self._pending: BagMessage | None = next(self._iter, None)
        self._wall0: int | None = None
        self._bag0: int = self._pending.log_time_nanos if self._pending else 0
        self.passes += 1

    def _due(self, msg: BagMessage, now: int) -> bool:
        if self.fast:
            return True
        if self._wall0 is None:
            self._wall0 = now
        bag_elapsed: float = (msg.log_time_nanos - self._bag0) / self.params.rate
        return bag_elapsed <= now - self._wall0

    def _tick(self) -> None:
        if self.done:
            return
        budget_end = time.monotonic() + self.params.batch_secs
        while time.monotonic() < budget_end:
            msg = self._pending
            if msg is None:
                if self.params.loop and self.published:
                    self._restart()
                    continue
                self._finish()
                return
            if not self._due(msg, self.io.now_nanos()):
                return
            topic = self.topic_map[msg.topic]
            decoded = self._decodable(msg, topic)
            if decoded is None:
                self._pending = next(self._iter, None)
                continue
            # Bound what is in flight: "as fast as the graph takes them", not faster (in
            # lockstep nothing is dropped at a high-water mark, but memory is finite).
            full = bool(self.params.window) and self._in_flight >= self.params.window
            if self.params.lockstep:
                if (full or self.io.lockstep_barrier(topic)) and not self._wait_idle(msg):
                    return
            elif full:
                if not self.io.wait_idle(self.params.idle_timeout_secs):
                    self.io.log.warning("graph not idle after %s s", self.params.idle_timeout_secs)
                self._in_flight = 0
            frames, typed = decoded
            self.io.publish_raw(topic, frames, typed)
            self.published += 1
            self._in_flight += 1
            self._pending = next(self._iter, None)

    def _decodable(self, msg: BagMessage, topic: str) -> tuple[list[Any], Message] | None:
        """The message's frames and itself if they decode into its type; else skip it (or
        stop: strict)."""
        schema = msg.channel.schema
        try:
            frames = msg.wire_frames(topic)
            _, typed = decode(frames, expect=self.kinds[msg.topic], stored=schema.description)
            if schema.fingerprint == typed.schema().fingerprint:
                return frames, typed
            return encode(topic, typed), typed  # an older declaration goes out as today's
        except BagError as err:
            problem = str(err)
        except FrameDecodeError as err:
            problem = f"{msg.where()}: {err}"
        if self.params.strict:
            raise NodeError(f"{self.name}: cannot decode (strict): {problem}")
        self.skipped += 1
        if self.skipped <= _LOGGED_SKIPS:
            more = "; later ones are counted only" if self.skipped == _LOGGED_SKIPS else ""
            self.io.log.warning("skipped, cannot decode: %s%s", problem, more)
        return None

    def _wait_idle(self, msg: BagMessage) -> bool:
        if self.io.wait_idle(self.params.idle_timeout_secs):
            self._in_flight = 0
            return True
        if self.io.stop_requested:
            self.done = True  # the graph is stopping; not a lockstep failure
            return False
        raise NodeError(
            f"{self.name}: graph not idle after {self.params.idle_timeout_secs} s before "
            f"message {self.published} ({msg.topic} at {msg.position()}); lockstep broken"
        )

    def _finish(self) -> None:
        self.done = True
        # Let the graph drain before asking it to stop, so the last outputs are not lost;
        # ``last``: what a node holds in stamp order waits for nothing more (lockstep).
        self.io.wait_idle(self.params.idle_timeout_secs, last=True)
        lost = self.reader.lost_messages
        problems = [f"{lost} lost to corrupt chunks"] if lost else []
        if self.skipped:
            problems.append(f"{self.skipped} skipped: could not be decoded")
        reason = f"replayed {self.published} messages from {self.params.path}" + (
            f" ({', '.join(problems)})" if problems else ""
        )
        self.io.log.info("%s", reason)
        if self.params.stop_when_done:
            self.io.request_stop(reason)

    def teardown(self) -> None:
        self.reader.close()
