"""The link between the launchers of one graph's hosts: heartbeats, clocks, stops.

Each host's launcher binds a ROUTER on the first port of its range (a CURVE server when
its address is not loopback, behind a :class:`runtime.security.Guard` that admits only
the graph's host keys and names the peer by its key) and connects one DEALER to each
other host's (a CURVE client with its own host's key pair). A thread owns these sockets,
so timestamps are taken the moment a message arrives, whatever the launcher is doing.

Messages are ``runtime.protocol`` control messages. Each launcher makes a fresh link
secret per run and sends it in ``link_hello`` (inside CURVE, and only accepted from the
connection whose key is that host's); every later message is tagged with the sender's
secret and checked. A peer that hears a message it cannot check (it restarted, or the
hello was sent before the connection was up) sends its own hello asking for a reply.

What the launcher learns comes out of :meth:`HostLink.events` as tuples:
``("joined", host)``, ``("graph_differs", host, its digest, ours, its command line,
ours)`` (its hello names another graph or run mode: it is not let in), ``("back", host)`` (a lost host speaks again; ``restarted`` says
whether it is a new launcher), ``("lost", host, silent_secs)`` after
``host_timeout_secs`` without a message (heartbeats also say whether the sender's nodes
are ready, see :meth:`HostLink.waiting_for`), ``("clock", host, offset_secs, round_trip_secs)``
once per incarnation (the NTP four-timestamp exchange, the sample with the shortest round
trip of ``CLOCK_SAMPLES``), and ``("stop", host, reason, exit_code)``.

In lockstep each launcher also passes on its nodes' newest counts (:meth:`HostLink.send_counts`)
and keeps the other hosts' (:meth:`HostLink.remote_counts`), so the idle barrier sees every
edge of the graph. Neither end waits on a timer for them: the link's thread sleeps in a poll
of its socket and of a pipe the launcher writes to when it queues a message, and it writes
to another pipe (:meth:`HostLink.fileno`) that the launcher polls with its control socket
whenever an event or counts arrive.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import msgpack
import zmq

from messages.control import (
    Control,
    FromHost,
    LinkBeat,
    LinkCounts,
    LinkFinal,
    LinkHello,
    LinkPing,
    LinkPong,
    LinkStop,
)
from runtime import protocol
from runtime.counters import balanced
from runtime.hosts import Hosts, HostSpec
from runtime.nodeprocs import Proc
from runtime.protocol import ControlError
from runtime.security import Guard, KeyPair, connect_to, serve

CLOCK_SAMPLES = 8
PING_TIMEOUT_SECS = 1.0
WHO_EVERY_SECS = 0.5
POLL_MS = 20
# How long a stopping link still tries to send a hello that is due.
FLUSH_HELLO_SECS = 1.5


@dataclass
class _Peer:
    spec: HostSpec
    dealer: zmq.Socket[Any]
    secret: bytes | None = None
    ready: bool = False  # its nodes are ready or running (its heartbeats say)
    differs: bytes | None = None  # the secret of its hello that named another graph
    last_seen: float = 0.0
    lost: bool = False
    asked_at: float = 0.0
    # A hello not sent yet (its ``reply`` flag): a DEALER with IMMEDIATE refuses a message
    # until its connection is up, so it is tried again on every turn of the thread until
    # it goes out. A hello lost to a connection still being made would leave a peer not
    # knowing of us (or of our graph) until the next turn of asking.
    hello_due: int | None = None
    ping_t1: int | None = None
    ping_sent_at: float = 0.0
    samples: list[tuple[float, float]] = field(default_factory=list)
    # Its nodes' newest counts (lockstep): published per topic, received per "node/port".
    counts: tuple[dict[str, int], dict[str, int], dict[str, int]] = ({}, {}, {})
    pending: dict[str, int] = field(default_factory=dict)  # "node/port": in stamp order
    last: bool = False  # its replay has sent its last message
    final: dict[str, int] | None = None  # what its nodes published in all, once stopped


class HostLink:
    """This host's end of the launchers' link (see the module's docstring)."""

    def __init__(
        self,
        ctx: zmq.Context[Any],
        hosts: Hosts,
        me: str,
        keys: KeyPair | None,
        log: Callable[[str], None],
        run: Mapping[str, Any],
        argv: str = "",
    ) -> None:
        self.me = me
        # Every host must run the same graph (the same nodes on the same ports; a recorder
        # added by --record is one of them) in the same mode (lockstep): a digest of ``run``.
        text = json.dumps(run, sort_keys=True, default=str).encode()
        self.graph = hashlib.sha256(text).hexdigest()
        self.argv = argv
        self.timeout = hosts.host_timeout_secs
        self.secret = protocol.new_secret()
        self.refused = 0
        self.log = log
        self._events: deque[tuple[Any, ...]] = deque()
        self._outbox: deque[list[bytes]] = deque()
        self._stopping = threading.Event()
        self._closed = False  # its pipes closed: their numbers may be another file's now
        self._ready = False
        self._beat_now = threading.Event()
        own = hosts.table[me]
        authorized = {h.public_key: h.name for h in hosts.table.values() if h.public_key}
        self.curve = keys is not None and not own.loopback
        self.guard: Guard | None = None
        self.router = ctx.socket(zmq.ROUTER)
        self.router.setsockopt(zmq.LINGER, 0)
        self.router.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_CONTROL_BYTES)
        if self.curve:
            assert keys is not None
            self.guard = Guard(ctx, authorized, lambda text: log(f"link: {text}"))
            serve(self.router, keys)
            self.guard.watch(self.router)
        self.router.bind(own.link)
        self.ctx, self.keys = ctx, keys
        self.peers = {
            name: _Peer(spec, self._dealer(spec))
            for name, spec in hosts.table.items()
            if name != me
        }
        # Wake-ups: the launcher -> this thread (a message queued), and back (something came).
        self._wake_r, self._wake_w = os.pipe()
        self._note_r, self._note_w = os.pipe()
        for fd in (self._wake_r, self._wake_w, self._note_r, self._note_w):
            os.set_blocking(fd, False)
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _dealer(self, spec: HostSpec) -> zmq.Socket[Any]:
        """A connection to the host ``spec`` (its link's ROUTER)."""
        dealer: zmq.Socket[Any] = self.ctx.socket(zmq.DEALER)
        dealer.setsockopt(zmq.LINGER, 500)
        dealer.setsockopt(zmq.IMMEDIATE, 1)  # nothing queued for a host that is down
        if not spec.loopback:
            assert self.keys is not None and spec.public_key is not None
            connect_to(dealer, self.keys, spec.public_key)
        dealer.connect(spec.link)
        return dealer

    # -- the launcher's side ----------------------------------------------------------------
    def start(self) -> None:
        if self.guard is not None:
            self.guard.start()
        self._thread.start()

    def fileno(self) -> int:
        """A pipe that turns readable when an event or counts arrive (for the launcher's poll)."""
        return self._note_r

    def events(self) -> list[tuple[Any, ...]]:
        if not self._closed:
            _drain_pipe(self._note_r)
        out = []
        while self._events:
            out.append(self._events.popleft())
        return out

    def set_ready(self) -> None:
        """This host's nodes are ready: say so at once (and in every heartbeat after)."""
        if not self._ready:
            self._ready = True
            self._beat_now.set()
            self._wake()

    def waiting_for(self) -> list[str]:
        """The other hosts not yet ready: a host starts its nodes when this is empty, so
        the graph starts on every host at once."""
        return [name for name, peer in self.peers.items() if not peer.ready]

    def send_stop(self, reason: str, exit_code: int) -> None:
        """Tell every other host the graph stops (sent by the link's thread)."""
        self._queue(self._pack(LinkStop, reason=reason, exit_code=exit_code))

    def send_counts(
        self,
        published: dict[str, int],
        received: dict[str, int],
        held: dict[str, int],
        *,
        pending: dict[str, int] | None = None,
        last: bool = False,
    ) -> None:
        """This host's nodes' newest counts (lockstep): published per topic, received,
        held and pending (``runtime.ordering``) per ``"node/port"``; each node's are one
        snapshot, taken after a handled batch. ``last``: this host's replay has sent its
        last message."""
        self._queue(
            self._pack(
                LinkCounts,
                published=published,
                received=received,
                held=held,
                pending=pending or {},
                last=int(last),
            )
        )

    def remote_pending(self) -> tuple[dict[str, int], bool]:
        """What the other hosts' nodes hold in stamp order (``"node/port"``), and whether
        one of their replays has sent its last message."""
        pending: dict[str, int] = {}
        for peer in self.peers.values():
            pending.update(peer.pending)
        return pending, any(peer.last for peer in self.peers.values())

    def remote_counts(self) -> tuple[dict[str, int], dict[str, int], dict[str, int]]:
        """The other hosts' newest counts, merged (as :meth:`send_counts` takes them)."""
        out: tuple[dict[str, int], dict[str, int], dict[str, int]] = ({}, {}, {})
        for peer in self.peers.values():
            theirs = peer.counts  # replaced whole by the link's thread, never changed
            for mine, their in zip(out, theirs, strict=True):
                mine.update(their)
        return out

    def send_final(self, published: dict[str, int]) -> None:
        """This host's nodes have stopped (but for listeners): all they published, per topic."""
        self._queue(self._pack(LinkFinal, published=published))

    def finals(self) -> dict[str, int] | None:
        """All the other hosts' nodes published, per topic, once every host that is not
        lost has sent :meth:`send_final`; None until then."""
        peers = [p for p in self.peers.values() if not p.lost]
        if any(p.final is None for p in peers):
            return None
        return {t: n for p in peers for t, n in (p.final or {}).items()}

    def _queue(self, frames: list[bytes]) -> None:
        self._outbox.append(frames)
        self._wake()

    def _wake(self) -> None:
        """Wake the link's thread (not once closed: the pipe's number may be reused)."""
        if not self._closed:
            _poke(self._wake_w)

    def _event(self, event: tuple[Any, ...]) -> None:
        self._events.append(event)
        _poke(self._note_w)

    def close(self) -> None:
        """Stop the thread, then close the sockets and pipes. After this the link touches
        no descriptor: its pipes' numbers go to the next file opened (libzmq's mailboxes
        among them), and a read or write on one there loses another object's wake-up. The
        thread ends within ``FLUSH_HELLO_SECS`` and a turn (it never blocks), so it is
        waited for: the sockets cannot be closed under it."""
        if self._closed:
            return
        self._stopping.set()
        self._wake()
        if self._thread.is_alive():
            self._thread.join()
        self._closed = True
        for fd in (self._wake_r, self._wake_w, self._note_r, self._note_w):
            os.close(fd)
        self.router.close(linger=0)
        if self.guard is not None:  # after the router: see Guard.close
            self.guard.close()
        for peer in self.peers.values():
            peer.dealer.close()

    # -- the thread -------------------------------------------------------------------------
    def _pack(self, kind: type[FromHost], **fields: Any) -> list[bytes]:
        return protocol.pack(self.secret, kind(host=self.me, **fields))

    def _hello(self, reply: int) -> list[bytes]:
        return self._pack(
            LinkHello,
            run_secret=self.secret.hex(),
            reply=reply,
            graph=self.graph,
            argv=self.argv,
        )

    def _send(self, peer: _Peer, frames: list[bytes]) -> bool:
        """Whether the message went out (False: no connection to the peer yet)."""
        try:
            peer.dealer.send_multipart(frames, zmq.NOBLOCK)
        except zmq.Again:
            return False  # not connected (yet): the heartbeat repeats, a hello is kept due
        return True

    def _say_hello(self, peer: _Peer, reply: int) -> None:
        """Send a hello now, or as soon as the connection to ``peer`` takes it."""
        peer.hello_due = max(reply, peer.hello_due or 0)
        if self._send(peer, self._hello(reply=peer.hello_due)):
            peer.hello_due = None
            if reply:
                peer.asked_at = time.monotonic()
            # A beat right after it: the peer could not check the last one (or, asked,
            # it waits for our readiness while our nodes may already run).
            self._beat_now.set()

    def _run(self) -> None:
        next_beat = 0.0
        for peer in self.peers.values():
            peer.hello_due = 1  # introduce ourselves: the peer learns our graph at once
        poller = zmq.Poller()
        poller.register(self.router, zmq.POLLIN)
        poller.register(self._wake_r, zmq.POLLIN)
        stop_by: float | None = None
        while True:
            _drain_pipe(self._wake_r)
            stopping = self._stopping.is_set()
            while self._outbox:
                frames = self._outbox.popleft()
                for peer in self.peers.values():
                    self._send(peer, frames)
            if stopping:
                # A hello still due goes out first (for FLUSH_HELLO_SECS at most): a
                # launcher that stops on a peer's differing graph would otherwise leave
                # the peer, which has not heard its own graph, waiting for it.
                stop_by = stop_by or time.monotonic() + FLUSH_HELLO_SECS
                due = [p for p in self.peers.values() if p.hello_due is not None]
                if not due or time.monotonic() > stop_by:
                    return
            now = time.monotonic()
            if now >= next_beat or self._beat_now.is_set():
                self._beat_now.clear()
                next_beat = now + protocol.HEARTBEAT_SECS
                beat = self._pack(LinkBeat, ready=int(self._ready))
                for peer in self.peers.values():
                    self._send(peer, beat)
            for peer in self.peers.values():
                self._tend(peer, now)
            # Wakes at once for a message in (the router) or out (the pipe); at the latest
            # after POLL_MS, for the heartbeats and the timeouts.
            if self.router in dict(poller.poll(POLL_MS)):
                while True:
                    try:
                        frames = self.router.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    self._receive(frames, time.time_ns())

    def _tend(self, peer: _Peer, now: float) -> None:
        """A hello still due, pings for the clock, and the heartbeat timeout."""
        if peer.hello_due is not None:
            self._say_hello(peer, peer.hello_due)
        if peer.secret is not None and len(peer.samples) < CLOCK_SAMPLES:
            if peer.ping_t1 is None or now - peer.ping_sent_at > PING_TIMEOUT_SECS:
                peer.ping_t1 = time.time_ns()
                peer.ping_sent_at = now
                self._send(peer, self._pack(LinkPing, t1=peer.ping_t1))
        # A peer that sent its final counts has stopped its nodes and may exit: its silence
        # then is its orderly end, not a loss (a host still stopping, its recorder writing,
        # must not call the other lost and fail the run).
        silent = now - peer.last_seen > self.timeout
        if peer.last_seen and not peer.lost and peer.final is None and silent:
            peer.lost = True
            self._event(("lost", peer.spec.name, now - peer.last_seen))

    def _refuse(self, why: str) -> None:
        self.refused += 1
        if self.refused <= protocol.REFUSED_LOG_FIRST or self.refused % 100 == 0:
            self.log(f"link: refused message #{self.refused}: {why}")

    def _ask(self, peer: _Peer) -> None:
        if peer.hello_due is None and time.monotonic() - peer.asked_at > WHO_EVERY_SECS:
            self._say_hello(peer, 1)

    def _receive(self, frames: list[zmq.Frame], arrived_ns: int) -> None:
        if len(frames) != 3:
            self._refuse(f"{len(frames) - 1} frame(s), expected 2")
            return
        payload, tag = frames[1].bytes, frames[2].bytes
        try:
            head = msgpack.unpackb(payload, raw=False)
            host, kind = head["host"], head["kind"]
        except (ValueError, TypeError, KeyError, msgpack.UnpackException):
            self._refuse("not a link message")
            return
        peer = self.peers.get(host) if isinstance(host, str) else None
        if peer is None:
            self._refuse(f"from {host!r:.40}, not another host of the graph")
            return
        if self.curve:
            try:
                user = frames[1].get("User-Id")
            except zmq.ZMQError:
                user = None
            if user != host:
                self._refuse(f"claims to be host {host!r}, but its key is {user!r}'s")
                return
        try:
            if kind == "link_hello":  # tagged with the secret it carries
                secret = bytes.fromhex(str(head.get("run_secret")))
                msg = protocol.unpack(secret, [payload, tag], from_node=False)
            elif peer.secret is None:
                self._ask(peer)
                return
            else:
                msg = protocol.unpack(peer.secret, [payload, tag], from_node=False)
        except (ControlError, ValueError) as err:
            self._ask(peer)  # most likely a new launcher there whose hello is still to come
            self._refuse(f"from host {host!r}: {err}")
            return
        self._on_message(peer, msg, arrived_ns)

    def _on_message(self, peer: _Peer, msg: Control, arrived_ns: int) -> None:
        name = peer.spec.name
        if isinstance(msg, LinkHello):
            secret = bytes.fromhex(msg.run_secret)
            if msg.reply:  # also to another graph: then it learns so too, and stops
                self._say_hello(peer, 0)
            if msg.graph != self.graph:  # its endpoints and nodes are not ours
                if secret != peer.differs:
                    peer.differs = secret
                    self._event(("graph_differs", name, msg.graph, self.graph, msg.argv, self.argv))
                return
            if secret != peer.secret:
                first = peer.secret is None and not peer.last_seen
                peer.secret = secret
                peer.ready = False
                peer.samples = []
                peer.ping_t1 = None
                peer.counts = ({}, {}, {})
                peer.pending, peer.last = {}, False
                peer.final = None
                if first:
                    self._event(("joined", name))
                elif not peer.lost:  # restarted within the timeout
                    self._event(("back", name, True))
        elif isinstance(msg, LinkPing):
            self._send(peer, self._pack(LinkPong, t1=msg.t1, t2=arrived_ns, t3=time.time_ns()))
        elif isinstance(msg, LinkPong) and msg.t1 == peer.ping_t1:
            t1, t2, t3, t4 = msg.t1, msg.t2, msg.t3, arrived_ns
            peer.ping_t1 = None
            peer.samples.append((((t2 - t1) + (t3 - t4)) / 2e9, ((t4 - t1) - (t3 - t2)) / 1e9))
            if len(peer.samples) == CLOCK_SAMPLES:
                offset, rtt = min(peer.samples, key=lambda s: s[1])
                self._event(("clock", name, offset, rtt))
        elif isinstance(msg, LinkBeat):
            peer.ready = bool(msg.ready)
        elif isinstance(msg, LinkCounts):
            peer.counts = (msg.published, msg.received, msg.held)
            peer.pending, peer.last = msg.pending, bool(msg.last)
            _poke(self._note_w)
        elif isinstance(msg, LinkFinal):
            peer.final = msg.published
            _poke(self._note_w)
        elif isinstance(msg, LinkStop):
            self._event(("stop", name, msg.reason, msg.exit_code))
        peer.last_seen = time.monotonic()
        if peer.lost:
            peer.lost = False
            self._event(("back", name, isinstance(msg, LinkHello)))


def _poke(fd: int) -> None:
    try:
        os.write(fd, b"\0")
    except BlockingIOError:
        pass  # full: a wake-up is pending anyway


def _drain_pipe(fd: int) -> None:
    try:
        while os.read(fd, 4096):
            pass
    except BlockingIOError:
        pass  # empty


def wait_for_finals(
    link: HostLink,
    edges: list[tuple[str, str, str]],
    published: dict[str, int],
    listeners: list[Proc],
    step: Callable[[], bool],
    secs: float = 8.0,
) -> None:
    """Stopping: wait until every other host has stopped its nodes (:meth:`HostLink.finals`)
    and each of this host's ``listeners``, by its heartbeat after that, received all that
    was published on each of its ``edges`` (here: ``published``). ``step`` serves the
    launcher once and says whether to go on; at most ``secs``."""
    end = time.monotonic() + secs
    complete = 0.0  # when the last host's final counts came
    while time.monotonic() < end and step():
        finals = link.finals()
        if finals is None:
            continue
        complete = complete or time.monotonic()
        stats = {p.spec.name: p.stats for p in listeners if p.stats_at > complete}
        if len(stats) == len(listeners) and balanced(edges, stats, published | finals):
            return
