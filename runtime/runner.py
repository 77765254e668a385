"""One node, one OS process: ZeroMQ transport, handshake, heartbeats, clean stop.

Started by the launcher through ``runtime.child`` (a fork of its fork server, the
node's JSON spec on stdin), which sets up parent death and signals first.

Transport. The node binds one XPUB (verbose, so it sees every subscription) and
connects one SUB per input to the publisher of that input's topic. Frames are the
codec's multipart messages, sent and received without copying the arrays.

Input policies. ``queue``: messages are handled in order, bounded by the socket
high-water mark; each poll round handles what an input has waiting for up to
``_BATCH_NANOS`` before it turns to the next input and the timers (one poll per message
would cost a fast stream a fifth of its throughput). ``latest``: the
input is drained on every round and only the newest message is handled, so a slow
consumer never works through a backlog (ZeroMQ's CONFLATE cannot do multipart).

Lockstep (deterministic replay). Every input is a ``queue`` without a bound (the
replay bounds what is in flight), and a node reads each publisher through one SUB
socket subscribed to all the topics it takes from it, so it handles one publisher's
messages in the order they were published, whatever the topics. After each handled
message it reports its counts to the launcher, which tells a waiting replay when the
graph is idle; the replay waits only before messages on ``barrier_topics`` (those that
can reach a node merging several publishers, see ``Graph.barrier_topics``). A node's
timers are bag-driven there: each runs once after every message the node handles, not
by the clock (a pose node that solves the newest patch on a timer answers every patch),
unless the node is a source or declares itself ``clocked`` (a simulated world, a driver).

Stamp order. The inputs a node names in ``ordered_inputs`` (two or more of them wired)
go through a :class:`runtime.ordering.StampOrder`: each message waits until the other
ordered inputs have advanced past its stamp (live at most ``order_window_secs``), and is
handled by stamp, so a decision taken from inputs with paths of different lengths is
the same live and in a replay. Live, an input may wait for only some of the others
(``order_waits``). In lockstep the wait has no bound and every input waits for every
other; the launcher has the node hand over what it still holds once the replay has sent
its last message.

Drops. Every output stamps ``header.seq``; a receiver counts sequence gaps as
``dropped`` (lost at a high-water mark) and, on ``latest`` inputs, skipped messages
as ``superseded``. Frames that fail to decode are counted as ``bad_frames`` (not also
as dropped) and logged, and never stop the node; a seq that breaks the sequence is
believed only once the next message follows it (see :meth:`InputCounters.note_seq`).
Messages whose finite-by-meaning fields (``Message.finite_fields``) hold NaN or
infinity are counted as ``nonfinite`` per topic by their publisher (``IO.publish``),
warned about once there, and delivered: the receivers do not read the pixels again.

Handshake. hello (endpoint) -> connect (peers' endpoints) -> wait until every
expected subscription has arrived on the XPUB -> setup done -> ready -> start. No
node publishes before start, so no subscriber misses the first message.

Security. tcp on an address that is not loopback is CURVE (``runtime.security``): the
publisher is a CURVE server behind a ZAP handler that admits the graph's host keys only,
and each input a CURVE client with the host's key pair (handed on stdin with the spec).

Control. Every control message is signed with the run's secret and checked
(``runtime.protocol``); one that fails is logged and dropped.

Parent death. ``PR_SET_PDEATHSIG`` (set by ``runtime.child``) delivers SIGTERM when the
launcher dies, and the heartbeat thread checks the parent pid as a fallback.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any

import zmq

from messages.codec import decode
from messages.control import (
    Connect,
    Control,
    Final,
    Heartbeat,
    Hello,
    Ready,
    Release,
    Start,
    Stop,
)
from messages.errors import FrameDecodeError, NodeError
from runtime import protocol
from runtime.node import Node
from runtime.ordering import StampOrder
from runtime.params import build_params
from runtime.registry import resolve
from runtime.security import connect_to, needs_curve
from runtime.zmqio import Input, Source, ZmqIO, recv_parts

_BAD_FRAME_LOG_EVERY = 100
_BATCH_NANOS = 2_000_000


class Runner:
    """Runs one node: handshake, the poll loop, timers, heartbeats, clean stop."""

    def __init__(self, spec: dict[str, Any]) -> None:
        self.spec = spec
        self.name: str = spec["name"]
        self.ctx: zmq.Context[Any] = zmq.Context()
        self.io = ZmqIO(spec, self.ctx)
        cls = resolve(spec["class_path"])
        params = build_params(cls.Params, spec["params"])
        inputs_decl, outputs_decl = cls.ports(params)
        self.io.output_types = dict(outputs_decl)
        self.node: Node = cls(self.name, params, self.io)
        self.raw = cls.raw_input
        self.inputs_decl = inputs_decl
        # Lockstep: timers run after each handled message instead of by the clock.
        self.bag_driven = self.io.lockstep and bool(inputs_decl) and not cls.clocked
        # Lockstep, a node reading several publishers: hold, then handle in a fixed order.
        self.holds = self.io.lockstep and bool(spec.get("holds"))
        self.port_order = {inp["port"]: k for k, inp in enumerate(spec["inputs"])}
        ordered = [port for port in cls.ordered_inputs if port in self.port_order]
        window = None if self.io.lockstep else round(cls.order_window_secs * 1e9)
        self.order = StampOrder(ordered, window, cls.order_waits) if len(ordered) > 1 else None
        self.io.order = self.order
        self.flush = False  # lockstep: told to hand over what the stamp order holds
        self.busy_since = 0.0
        self.set_up = False  # teardown runs only for a node whose setup ran
        self.sources: list[Source] = []
        self.stopping = threading.Event()
        self._hb_thread = threading.Thread(target=self._heartbeat, daemon=True)
        # Each input's handler, looked up at its first message (see _handler).
        self.handlers: dict[str, Callable[[Any], None]] = {}

    # -- lifecycle -------------------------------------------------------------
    def run(self) -> int:
        io = self.io
        io.tell(Hello, endpoint=io.endpoint)
        self._hb_thread.start()
        connect = self._wait_control(Connect)
        if not isinstance(connect, Connect):
            return self._finish(0)
        by_key: dict[str, Source] = {}
        for inp in self.spec["inputs"]:
            # Outside lockstep a socket per input (its own bound and policy); in lockstep
            # a socket per publisher, which keeps that publisher's order across topics.
            key = inp["provider"] if io.lockstep else inp["port"]
            source = by_key.get(key)
            if source is None:
                sock = self.ctx.socket(zmq.SUB)
                sock.setsockopt(zmq.RCVHWM, 0 if io.lockstep else inp["queue_size"])
                sock.setsockopt(zmq.LINGER, 0)
                endpoint = connect.endpoints[inp["provider"]]
                if io.keys is not None and needs_curve(endpoint):
                    connect_to(sock, io.keys, self.spec["curve"]["servers"][inp["provider"]])
                sock.connect(endpoint)
                latest = inp["policy"] == "latest" and not io.lockstep
                source = by_key[key] = Source(sock, latest=latest)
                self.sources.append(source)
            topic = inp["topic"].encode()
            if topic not in source.inputs:
                source.socket.setsockopt(zmq.SUBSCRIBE, topic)
            kind = None if self.raw else self.inputs_decl[inp["port"]]
            entry = Input(inp["port"], inp["topic"], inp["policy"], kind)
            source.inputs.setdefault(topic, []).append(entry)
            io.inputs.append(entry)
        self._await_subscribers()
        self.busy_since = time.monotonic()
        self.node.setup()
        self.set_up = True
        self.busy_since = 0.0
        io.tell(Ready)
        if self._wait_control(Start) is None:
            return self._finish(0)
        self._loop()
        return self._finish(0)

    def _finish(self, code: int) -> int:
        self.stopping.set()
        try:
            if self.set_up:
                self.node.teardown()
        finally:
            self.io.tell(Final, stats=self.io.stats())
            for source in self.sources:
                source.socket.close(linger=0)
            self.io.pub.close(linger=1000)
            if self.io.guard is not None:
                self.io.guard.close()
            self.io.control.close(linger=1000)
            self._hb_thread.join(timeout=2)
            self.ctx.term()
        return code

    def _wait_control(self, kind: type[Control]) -> Control | None:
        """Wait for one control message, serving subscriptions meanwhile; None on stop."""
        poller = zmq.Poller()
        poller.register(self.io.control, zmq.POLLIN)
        poller.register(self.io.pub, zmq.POLLIN)
        while not self.io.stop_requested:
            events = dict(poller.poll(200))
            if self.io.pub in events:
                self._drain_subscriptions()
            if self.io.control in events:
                msg = self.io.hear()
                if isinstance(msg, Stop):
                    return None
                if isinstance(msg, kind):
                    return msg
        return None

    def _drain_subscriptions(self) -> None:
        while True:
            try:
                event = self.io.pub.recv(zmq.NOBLOCK)
            except zmq.Again:
                return
            if event[:1] == b"\x01":
                self.io.subscriptions[event[1:]] += 1

    def _await_subscribers(self) -> None:
        """Block until every expected subscriber of each output topic has subscribed."""
        expected: dict[str, int] = self.spec["expected_subscribers"]
        poller = zmq.Poller()
        poller.register(self.io.pub, zmq.POLLIN)
        poller.register(self.io.control, zmq.POLLIN)
        while not self.io.stop_requested and any(
            self.io.subscriptions[t.encode()] < n for t, n in expected.items()
        ):
            events = dict(poller.poll(200))
            if self.io.pub in events:
                self._drain_subscriptions()
            if self.io.control in events:
                msg = self.io.hear()
                if isinstance(msg, Stop):
                    self.io.stop_requested = True
                    return

    # -- the loop --------------------------------------------------------------
    def _loop(self) -> None:
        io = self.io
        poller = zmq.Poller()
        for source in self.sources:
            poller.register(source.socket, zmq.POLLIN)
        poller.register(io.control, zmq.POLLIN)
        poller.register(io.pub, zmq.POLLIN)
        by_socket = {source.socket: source for source in self.sources}
        while not io.stop_requested:
            timeout_ms = 200
            dues = [t.due_nanos for t in io.timers] if not self.bag_driven else []
            if self.order is not None and (held_until := self.order.due_nanos()) is not None:
                dues.append(held_until)
            if dues:
                due = min(dues)
                # Round up: rounding down would poll(0) through the last millisecond
                # before every timer, a busy spin that steals the CPU from peers.
                timeout_ms = max(0, min(timeout_ms, math.ceil((due - time.monotonic_ns()) / 1e6)))
            events = dict(poller.poll(timeout_ms))
            released = io.control in events and self._on_control()
            if io.pub in events:
                self._drain_subscriptions()
            handled = released and self._release()
            for sock, source in by_socket.items():
                if sock in events and not io.stop_requested:
                    handled |= self._service(source)
            if self.order is not None and not io.lockstep:
                self._pass(self.order.ready(time.monotonic_ns()))  # held past the window
            self._run_timers()
            if handled and io.lockstep:
                io.send_counts()

    def _on_control(self) -> bool:
        """Serve the launcher's messages; True when one released the held messages."""
        released = False
        while self.io.control.poll(0):
            msg = self.io.hear()
            if isinstance(msg, Stop):
                self.io.stop_requested = True
            if isinstance(msg, Release):
                released = True
                self.flush = self.flush or bool(msg.pending)
        return released

    def _release(self) -> bool:
        """Handle the held messages (lockstep, an ordered fan-in): by stamp, then by input
        in the graph's order, then as received. The launcher releases them once everything
        published has arrived, so what is held, and this order, depend on the bag alone."""
        held, self.io.held = self.io.held, []

        def key(item: tuple[int, tuple[Input, Any]]) -> tuple[int, int, int]:
            arrival, (inp, msg) = item
            header = getattr(msg, "header", None)
            stamp = header.stamp_nanos if header is not None else 0
            return (stamp, self.port_order[inp.port], arrival)

        for _, (inp, msg) in sorted(enumerate(held), key=key):
            self._admit(inp.port, msg)
        if self.flush and self.order is not None:
            # The replay has sent its last message: nothing the pending ones wait for comes.
            self.flush = False
            self._pass(self.order.flush())
            return True
        return bool(held)

    def _admit(self, port: str, msg: Any) -> None:
        """Handle ``msg`` now, or, on an ordered input, once the order allows it."""
        if self.order is not None and port in self.order:
            self.order.add(port, msg, time.monotonic_ns())
            self._pass(self.order.ready())
        elif not self.io.stop_requested:
            self._handle(port, msg)

    def _pass(self, messages: list[tuple[str, Any]]) -> None:
        for port, msg in messages:
            if not self.io.stop_requested:
                self._handle(port, msg)

    def _run_timers(self) -> None:
        if self.bag_driven:
            return  # they run after each message (_deliver)
        now = time.monotonic_ns()
        for timer in self.io.timers:
            # ``in``: not one an earlier callback of this round cancelled (a new list).
            if timer.due_nanos <= now and not self.io.stop_requested and timer in self.io.timers:
                # Skip missed periods rather than bursting to catch up.
                timer.due_nanos = max(timer.due_nanos + timer.period_nanos, now)
                self._call(timer.callback)

    def _service(self, source: Source) -> bool:
        got = self._recv(source, waiting=True)  # the poll has just said it has one
        if got is None:
            return False
        inputs, frames = got
        if source.latest:
            skipped = 0
            while (newer := self._recv(source)) is not None:
                skipped += 1
                frames = newer[1]
            inputs[0].counters.superseded += skipped
            inputs[0].counters.received += skipped
            self._deliver(inputs[0], frames, skipped)
            return True
        deadline = time.monotonic_ns() + _BATCH_NANOS
        while True:
            for inp in inputs:
                self._deliver(inp, frames)
            if self.io.stop_requested or time.monotonic_ns() >= deadline:
                return True
            if (got := self._recv(source)) is None:
                return True
            inputs, frames = got

    def _recv(
        self, source: Source, *, waiting: bool = False
    ) -> tuple[list[Input], list[Any]] | None:
        """The next message of an input of ``source`` and those inputs, or None
        (``waiting``: a poll has just said a message waits, see ``recv_parts``)."""
        while (frames := recv_parts(source.socket, waiting=waiting)) is not None:
            inputs = source.inputs.get(frames[0].bytes)
            if inputs:  # else another topic that merely starts with a subscribed one
                return inputs, frames
            waiting = False
        return None

    def _deliver(self, inp: Input, frames: list[Any], skipped: int = 0) -> None:
        """Decode and handle one message; ``skipped`` newer-than-last ones were superseded."""
        counters = inp.counters
        counters.received += 1
        if self.raw:
            self._call(self.node.on_raw, inp.topic, frames)
            return
        try:
            # Frame 0 is the input's topic: _recv found the input by it.
            _, msg = decode(frames, expect=inp.kind, topic=inp.topic)
        except FrameDecodeError as err:
            counters.bad_frames += 1
            counters.unseq += 1 + skipped
            if counters.bad_frames % _BAD_FRAME_LOG_EVERY == 1:
                self.io.log.warning("%s: bad frame #%d: %s", inp.port, counters.bad_frames, err)
            return
        header = getattr(msg, "header", None)
        if header is not None:
            counters.note_seq(header.seq, skipped)
        if self.holds:
            self.io.held.append((inp, msg))
        else:
            self._admit(inp.port, msg)

    def _handle(self, port: str, msg: Any) -> None:
        handler = self.handlers.get(port) or self._handler(port)
        # As _call does, without its call and argument tuple: this runs for every message.
        self.busy_since = time.monotonic()
        try:
            handler(msg)
        finally:
            self.busy_since = 0.0
        if self.bag_driven:
            for timer in self.io.timers:
                if not self.io.stop_requested and timer in self.io.timers:
                    self._call(timer.callback)

    def _handler(self, port: str) -> Callable[[Any], None]:
        """``port``'s handler: ``on_<port>``, bound once (what ``Node.handle`` looks up for
        every message), or the node's own ``handle`` where it overrides that dispatch."""
        node = self.node
        if type(node).handle is Node.handle:
            handler: Callable[[Any], None] = getattr(node, f"on_{port}")
        else:
            handler = functools.partial(node.handle, port)
        self.handlers[port] = handler
        return handler

    def _call(self, fn: Callable[..., None], *args: Any) -> None:
        """``fn(*args)``, timed as busy for the heartbeat (no closure per message)."""
        self.busy_since = time.monotonic()
        try:
            fn(*args)
        finally:
            self.busy_since = 0.0

    # -- heartbeat thread ------------------------------------------------------
    def _heartbeat(self) -> None:
        sock = self.ctx.socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(self.spec["control"])
        parent = self.spec["parent_pid"]
        try:
            while not self.stopping.wait(protocol.HEARTBEAT_SECS):
                if os.getppid() != parent:
                    os.kill(os.getpid(), signal.SIGTERM)
                    return
                since = self.busy_since
                busy = time.monotonic() - since if since and not self.io.waiting else 0.0
                self.io.tell(Heartbeat, sock, busy_secs=busy, stats=self.io.stats())
        finally:
            sock.close()


def main(spec: dict[str, Any]) -> int:
    """Run the node of ``spec`` (see ``runtime.child``, which calls this)."""
    logging.basicConfig(
        level=spec.get("log_level", "INFO"),
        format="%(levelname)s %(message)s",
        stream=sys.stdout,
        force=True,  # a fork of the launcher: whatever it configured is not this node's
    )
    runner = Runner(spec)

    def on_signal(signum: int, frame: Any) -> None:
        runner.io.stop_requested = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        return runner.run()
    except NodeError as err:
        # A node's own error names the node and says what is wrong: one line, no traceback.
        logging.getLogger(spec["name"]).error("%s", err)
        sys.stdout.flush()
        return 1
    except Exception:
        traceback.print_exc()
        sys.stdout.flush()
        return 1
