"""Start a checked graph as OS processes, supervise them, stop them, report.

One process per node (forked by ``runtime.child``), a control ROUTER socket for
the handshake, heartbeats, lockstep counters and stop requests (see
``runtime.protocol``). Supervision: a node that exits with an error, or whose
heartbeat stops, or that stays busy in one handler longer than its
``hang_timeout_secs``, is handled by its restart policy (``never``, or
``on-failure`` with exponential back-off and a cap); when a node marked
``required`` fails for good, the graph stops with a non-zero exit (the node's own
lines, printed as they came with its name, are not repeated). A node that is starting (first start or restart) has
``STARTUP_TIMEOUT_SECS`` to say ready; the heartbeat rule applies once it runs.
Stopping (Ctrl-C, SIGTERM, ``--duration``, a node's request): every node is asked to
stop, then terminated after a grace period, then killed; after a signal the whole
stop takes at most ``SIGNAL_STOP_SECS`` and the exit code is 128 + the signal's
number. Children die with the launcher even on SIGKILL (``runtime.child``), and the
last of them removes the run folder. Control messages are signed with a per-run
secret and checked (``runtime.protocol``); a bad one is counted and logged.
"""

from __future__ import annotations

import os
import shutil
import signal
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import IO, Any

import zmq

from messages.control import (
    Busy,
    Connect,
    Control,
    Counts,
    Final,
    FromNode,
    Heartbeat,
    Hello,
    Idle,
    Ready,
    Release,
    Start,
    Stop,
    StopRequest,
    WaitIdle,
)
from runtime import child, nodeprocs, protocol, status
from runtime.counters import balanced, delivered
from runtime.graph import Graph, ipc_path
from runtime.hostlink import HostLink, wait_for_finals
from runtime.hostpolicy import judge
from runtime.isolation import make_rundir
from runtime.nodeprocs import (
    Proc,
    counts,
    pending,
    reap,
    signal_group,
    spawn,
    stop,
    table,
    totals,
)
from runtime.protocol import ControlServer
from runtime.registry import class_path
from runtime.security import KeyPair

STARTUP_TIMEOUT_SECS = 300.0
HEARTBEAT_TIMEOUT_SECS = 5.0
DRAIN_SECS = 3.0
BUSY_EVERY_SECS = 1.0  # at most this often, a waiter for idle hears the graph still moves
STOP_GRACE_SECS = 5.0
TERM_GRACE_SECS = 2.0
# After Ctrl-C or SIGTERM: "stop", then SIGTERM, then SIGKILL, all within 2 s.
SIGNAL_STOP_GRACE_SECS = 1.0
SIGNAL_TERM_GRACE_SECS = 0.5


class Launcher:
    """Runs one graph to the end; :meth:`run` returns the exit code."""

    def __init__(
        self,
        graph: Graph,
        *,
        lockstep: bool = False,
        duration_secs: float | None = None,
        log_level: str = "INFO",
        out: IO[str] | None = None,
        host: str | None = None,
        keys: KeyPair | None = None,
        argv: str = "",
    ) -> None:
        self.graph = graph
        self.argv = argv  # the command line, for the other hosts to say which flags differ
        # With a hosts table: only this host's nodes, every publisher at its fixed endpoint.
        self.host, self.keys = host, keys
        placed = graph.hosts.placement({n: s.host for n, s in graph.nodes.items()})
        self.fixed = graph.hosts.endpoints(placed) if host else {}
        local = {n for n in graph.nodes if not host or placed[n] == host}
        self.lockstep = lockstep
        self.duration_secs = duration_secs
        self.log_level = log_level
        self.out = out or sys.stdout
        self.procs = {name: Proc(spec) for name, spec in graph.nodes.items() if name in local}
        self.servers = {
            n: graph.hosts.table[h].public_key for n, h in placed.items() if self.fixed and keys
        }
        self.providers = {topic: node for topic, (node, _) in graph.providers().items()}
        # Subscriptions each publisher waits for: one per input, but in lockstep a node
        # reads each publisher through one socket, subscribed once per topic.
        self.expected: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
        self.edges = edges = graph.edges()
        subscriptions = {(t, n) for t, n, _ in edges} if lockstep else [(t, n) for t, n, _ in edges]
        for topic, _ in subscriptions:
            self.expected[self.providers[topic]][topic] += 1
        # The edges this launcher sees both ends of (all of them on one host).
        self.local_edges = [e for e in edges if {e[1], self.providers[e[0]]} <= local]
        # Listeners (a recorder) fed from another host: stopped last (see ``_shutdown``).
        remote = {n for t, n, _ in edges if n in local and self.providers[t] not in local}
        self.held = {n for n in remote if graph.nodes[n].cls.raw_input}
        self.barrier_topics = graph.barrier_topics() if lockstep else set()
        self.fan_ins = graph.fan_ins() if lockstep else set()
        self.release_order = graph.release_order() if lockstep else []
        self.stop_reason: str | None = None
        self.exit_code = 0
        self.verdict_code = 0  # a node's verdict on the run (stop_request's exit_code)
        self.idle_waiters: list[bytes] = []
        self.last_sent = False  # a source waited for idle after its last message (lockstep)
        # What the graph had received when a waiter was last told it is busy (see _serve).
        self.received_total = 0
        self.received_told = -1
        self.busy_told_at = 0.0
        self.counts_changed = False  # lockstep across hosts: to send to the other hosts
        self.started_at = 0.0
        self.stopped_at = 0.0
        self._print_lock = threading.Lock()
        self._signals: list[int] = []
        self.secret = protocol.new_secret()
        self.rundir: Path | None = None
        self.starter: child.Starter | None = None
        self.ctx: zmq.Context[Any] | None = None
        self.link: HostLink | None = None

    def _open(self) -> None:
        """The run folder (for ``ipc://`` endpoints), the fork server, the control socket."""
        self.rundir = make_rundir()
        # Forked before any socket or thread of the launcher exists (runtime.child).
        self.starter = child.Starter(self.rundir)
        self.ctx = zmq.Context()
        self.control_endpoint = f"ipc://{self.rundir}/control"
        self.control = ControlServer(self.ctx, self.control_endpoint, self.secret, self.say)
        if self.host is not None:
            hosts = self.graph.hosts
            run = {"graph": self.graph.document, "lockstep": self.lockstep}  # must agree
            self.link = HostLink(self.ctx, hosts, self.host, self.keys, self.say, run, self.argv)
            self.link.start()
        self.poller = zmq.Poller()
        self.poller.register(self.control.socket, zmq.POLLIN)
        if self.link is not None:
            self.poller.register(self.link.fileno(), zmq.POLLIN)

    def _close(self) -> None:
        if self.starter is not None:
            self.starter.close()
        if self.link is not None:
            self.link.close()
        if self.ctx is not None:
            self.control.close()
            self.ctx.term()
        if self.rundir is not None:
            shutil.rmtree(self.rundir, ignore_errors=True)

    # -- output ----------------------------------------------------------------
    def say(self, text: str, node: str = "launch") -> None:
        with self._print_lock:
            for line in text.splitlines() or [""]:
                print(f"[{node}] {line}", file=self.out, flush=True)

    # -- processes ---------------------------------------------------------------
    def _bind_endpoint(self, proc: Proc) -> str:
        if proc.endpoint:  # a restart binds where the subscribers already connect
            return proc.endpoint
        if self.fixed:
            return self.fixed[proc.spec.name]
        if proc.spec.host:
            return f"tcp://{proc.spec.host}:*"
        assert self.rundir is not None, "the run folder is made before any node starts"
        return f"ipc://{ipc_path(self.rundir, proc.spec.name)}"

    def _spawn(self, proc: Proc) -> None:
        spec = proc.spec
        child_spec = {
            "name": spec.name,
            "class_path": class_path(spec.cls),
            "params": spec.raw_params,
            "outputs": spec.topics,
            "inputs": [
                {
                    "port": i.port,
                    "topic": i.topic,
                    "provider": self.providers[i.topic],
                    "policy": i.policy,
                    "queue_size": i.queue_size,
                }
                for i in spec.inputs.values()
            ],
            "expected_subscribers": dict(self.expected[spec.name]),
            "bind": self._bind_endpoint(proc),
            "control": self.control_endpoint,
            "secret": self.secret.hex(),
            "parent_pid": os.getpid(),
            "lockstep": self.lockstep,
            "barrier_topics": sorted(self.barrier_topics & set(spec.topics.values())),
            "holds": spec.name in self.fan_ins,
            "log_level": self.log_level,
        }
        if self.keys is not None:  # the host's own key pair and the publishers' keys
            child_spec["curve"] = {
                "public": self.keys.public,
                "secret": self.keys.secret,
                "authorized": {h.public_key: n for n, h in self.graph.hosts.table.items()},
                "servers": self.servers,
            }
        assert self.rundir is not None
        assert self.starter is not None
        spawn(proc, self.starter.start(), child_spec, self.say)

    def _reap(self) -> None:
        for proc in self.procs.values():
            if proc.process is None or proc.state in ("exited", "failed", "waiting_restart"):
                continue
            code = reap(proc)
            if code is None:
                continue
            self._on_exit(proc, code)

    def _on_exit(self, proc: Proc, code: int) -> None:
        if code != 0 and self.stop_reason is None:
            self._failed(proc, nodeprocs.exit_reason(code))
            return
        proc.state = "exited"
        if code != 0 and not nodeprocs.ended_by_launcher(proc, code):
            # Failing while the graph stops (a recorder whose disk filled) fails the run too.
            self._ended_badly(proc, f"{nodeprocs.exit_reason(code)} while the graph stopped")

    def _ended_badly(self, proc: Proc, why: str) -> None:
        """A node that failed where no restart can follow: the run fails if it is required."""
        if proc.spec.required:
            self.say(f"required node {proc.spec.name!r} failed ({why})")
            self.exit_code = 1
        else:
            self.say(f"node {proc.spec.name!r} failed ({why}); not required")

    def _failed(self, proc: Proc, reason: str) -> None:
        name = proc.spec.name
        policy = proc.spec.restart
        if policy.policy == "on-failure" and proc.restarts < policy.max_restarts:
            delay = min(policy.backoff_secs * 2 ** min(proc.restarts, 64), policy.backoff_max_secs)
            proc.restarts += 1
            proc.state = "waiting_restart"
            proc.restart_at = time.monotonic() + delay
            self.say(
                f"node {name!r} failed ({reason}); restart {proc.restarts}/{policy.max_restarts} in {delay:.2f} s"
            )
            return
        proc.state = "failed"
        if proc.spec.required:
            # Its output was printed as it came, marked with its name: not repeated here.
            self.say(f"required node {name!r} failed ({reason}); stopping the graph")
            self.exit_code = 1
            self._request_stop(f"required node {name!r} failed")
        else:
            self.say(f"node {name!r} failed ({reason}); not required, the graph goes on")

    def _kill_hung(self, proc: Proc, why: str) -> None:
        signal_group(proc, signal.SIGKILL)
        self.say(f"node {proc.spec.name!r} {why}; killed")

    # -- control messages --------------------------------------------------------
    def _send(self, name: str, msg: Control) -> None:
        self.control.send(self.procs[name].rid, msg)

    def _on_message(self, proc: Proc, rid: bytes, msg: FromNode) -> None:
        name = proc.spec.name
        proc.last_heartbeat = time.monotonic()
        if isinstance(msg, Hello):
            proc.rid = rid  # where this incarnation's main socket hears the launcher
            proc.endpoint = msg.endpoint
            proc.state = "hello"
            if self.started_at:  # a restart: peers' endpoints are known
                self._send(name, Connect(endpoints=self._endpoints()))
        elif isinstance(msg, Ready):
            proc.state = "ready"
            if self.started_at:
                self._send(name, Start())
                proc.state = "running"
                if proc.restarts:
                    self.say(f"node {name!r} is back")
        elif isinstance(msg, Heartbeat):
            proc.busy_secs = msg.busy_secs
            proc.stats = msg.stats
            proc.stats_at = time.monotonic()
        elif isinstance(msg, Final):
            proc.stats = msg.stats
        elif isinstance(msg, Counts):
            proc.counts_published = msg.published
            proc.counts_received = msg.received
            proc.counts_held = msg.held
            proc.counts_pending = msg.pending
            proc.released = False
            self.counts_changed = True
        elif isinstance(msg, WaitIdle):
            self.idle_waiters.append(rid)
            if msg.last and not self.last_sent:
                self.last_sent = self.counts_changed = True  # the other hosts learn it too
        elif isinstance(msg, StopRequest):
            reason = msg.reason
            verdict = msg.exit_code
            if verdict:
                self.verdict_code = self.verdict_code or verdict
                self.say(f"node {name!r} reports failure (exit code {verdict}): {reason}")
            if self.lockstep and self.graph.nodes[name].inputs:
                # A replay runs ahead of its consumers by up to its window, so where such
                # a request would cut the bag depends on timing: in lockstep the sources
                # (the replay) end the run, and the outputs stay the same run to run.
                self.say(
                    f"node {name!r} asks to stop ({reason}): lockstep, the replay ends the run"
                )
                return
            self.say(f"node {name!r} asks to stop: {reason}")
            self._request_stop(f"{name}: {reason}")

    def _endpoints(self) -> dict[str, str]:
        return self.fixed | {name: p.endpoint for name, p in self.procs.items() if p.endpoint}

    def _graph_idle(self) -> bool:
        """Whether every edge received all published on it (other hosts' counts from the
        link: stale ones only make the graph look busy, see docs/hosts.md)."""
        published, received, held = counts(self.procs)
        waiting, last = pending(self.procs), self.last_sent
        if self.link is not None:
            theirs, got, kept = self.link.remote_counts()
            published, received, held = theirs | published, got | received, kept | held
            their_pending, their_last = self.link.remote_pending()
            waiting, last = their_pending | waiting, last or their_last
        self.received_total = sum(received.values())
        arrived = delivered(self.edges, published, lambda n, port: received.get(f"{n}/{port}", 0))
        if arrived and held:
            # Everything published has arrived, and only ordered fan-ins hold messages:
            # nothing else is on its way to them. The first of them upstream handles what
            # it holds (Graph.release_order); what it publishes is held in turn downstream.
            holding = {key.rsplit("/", 1)[0] for key in held}
            first = next((n for n in self.release_order if n in holding), "")
            proc = self.procs.get(first)  # another host's: its own launcher releases it
            if proc is not None and not proc.released:
                proc.released = True  # once, until its next counts
                self.control.send(proc.rid, Release())
        # Messages waiting in a node's stamp order (runtime.ordering) wait for later ones,
        # which come until the source has sent its last message; then they go, the
        # nodes upstream first, as the held ones do.
        flush = last and bool(waiting)
        if arrived and not held and flush:
            holding = {key.rsplit("/", 1)[0] for key in waiting}
            first = next((n for n in self.release_order if n in holding), "")
            proc = self.procs.get(first)  # another host's: its own launcher releases it
            if proc is not None and not proc.released:
                proc.released = True
                self.control.send(proc.rid, Release(pending=1))
        return arrived and not held and not flush

    def _serve(self, timeout_ms: int) -> None:
        # Wakes for a node's message or for the link's (an event, or another host's counts).
        self.poller.poll(timeout_ms)
        for rid, msg in self.control.receive(0):
            proc = self.procs.get(msg.node)
            if proc is None:
                self.control.refuse(f"signed, but names no node of the graph: {msg.node!r:.40}")
            else:
                self._on_message(proc, rid, msg)
        if self.link is not None:
            for event in self.link.events():
                act = judge(event, self.graph.hosts)
                for line in act.lines:
                    self.say(line)
                if act.stop is not None:
                    self.exit_code = self.exit_code or act.exit_code
                    self.verdict_code = self.verdict_code or act.verdict_code
                    self._request_stop(act.stop, echo=act.echo)
        if self.counts_changed and self.link is not None:
            self.counts_changed = False
            self.link.send_counts(
                *counts(self.procs), pending=pending(self.procs), last=self.last_sent
            )
        idle = self.lockstep and self._graph_idle()  # also releases what fan-ins hold
        if self.idle_waiters and idle:
            for rid in self.idle_waiters:
                self.control.send(rid, Idle())
            self.idle_waiters.clear()
        elif self.idle_waiters and time.monotonic() - self.busy_told_at > BUSY_EVERY_SECS:
            # Slow is not stuck: a waiter's timeout counts from the graph's last progress.
            if self.received_total != self.received_told:
                self.received_told = self.received_total
                self.busy_told_at = time.monotonic()
                for rid in self.idle_waiters:
                    self.control.send(rid, Busy())

    # -- run ---------------------------------------------------------------------
    def _request_stop(self, reason: str, *, echo: bool = True) -> None:
        """Stop the graph; ``echo``: tell the other hosts (not when one of them said it)."""
        if self.stop_reason is None:
            self.stop_reason = reason
            if echo and self.link is not None:
                self.link.send_stop(reason, self.exit_code or self.verdict_code)

    def _on_signal(self, signum: int, frame: Any) -> None:
        self._signals.append(signum)
        self._request_stop(f"signal {signal.Signals(signum).name}")
        if len(self._signals) >= 3:  # an impatient user: no more grace
            for proc in self.procs.values():
                signal_group(proc, signal.SIGKILL)

    def _startup(self) -> bool:
        for proc in self.procs.values():
            if self.stop_reason is not None:
                return False
            self._spawn(proc)
        deadline = time.monotonic() + STARTUP_TIMEOUT_SECS
        connected = False
        said: list[str] = []
        while self.stop_reason is None:
            self._serve(100)
            self._reap()
            if self._signals:
                # A signal while serving (a third Ctrl-C kills every node at once): the
                # nodes' deaths are the user's stop, not a failed start-up.
                break
            if any(p.state in ("failed", "waiting_restart", "exited") for p in self.procs.values()):
                bad = [
                    n
                    for n, p in self.procs.items()
                    if p.state in ("failed", "waiting_restart", "exited")
                ]
                self.say(f"node(s) {bad} died during start-up (their output is above)")
                self.exit_code = 1
                return False
            if not connected and all(p.state in ("hello", "ready") for p in self.procs.values()):
                endpoints = self._endpoints()
                for name in self.procs:
                    self._send(name, Connect(endpoints=endpoints))
                connected = True
            ready = connected and all(p.state == "ready" for p in self.procs.values())
            if ready and self.link is not None:  # every host starts its nodes at once
                self.link.set_ready()
                waiting = self.link.waiting_for()
                if waiting and waiting != said:
                    self.say(f"ready; waiting for host(s) {waiting}")
                said, ready = waiting, not waiting
            if ready:
                for name, proc in self.procs.items():
                    self._send(name, Start())
                    proc.state = "running"
                return True
            if time.monotonic() > deadline:
                waiting = [n for n, p in self.procs.items() if p.state != "ready"] + said
                self.say(
                    f"start-up timed out after {STARTUP_TIMEOUT_SECS:.0f} s waiting for {waiting}"
                )
                self.exit_code = 1
                return False
        return False

    def _supervise(self) -> None:
        deadline = None if self.duration_secs is None else time.monotonic() + self.duration_secs
        published_at = 0.0
        while self.stop_reason is None:
            self._serve(100)
            self._reap()
            now = time.monotonic()
            if now - published_at >= status.WRITE_EVERY_SECS and self.rundir is not None:
                published_at = now  # for `launch.py topic` (runtime.status)
                status.write(
                    self.rundir, status.snapshot(self.graph, self.procs, now - self.started_at)
                )
            for proc in self.procs.values():
                if proc.state == "waiting_restart" and now >= proc.restart_at:
                    self._spawn(proc)
                elif proc.state in ("new", "hello", "ready"):
                    # A restart is a start: the same allowance as the first one (it may be
                    # importing torch or building a solver, and sends no heartbeat yet).
                    if now - proc.spawned_at > STARTUP_TIMEOUT_SECS:
                        self._kill_hung(proc, f"did not start within {STARTUP_TIMEOUT_SECS:.0f} s")
                        proc.spawned_at = now
                elif proc.state == "running":
                    if now - proc.last_heartbeat > HEARTBEAT_TIMEOUT_SECS:
                        self._kill_hung(
                            proc, f"sent no heartbeat for {HEARTBEAT_TIMEOUT_SECS:.0f} s"
                        )
                        proc.last_heartbeat = now
                    elif proc.busy_secs > proc.spec.hang_timeout_secs:
                        self._kill_hung(proc, f"busy in one handler for {proc.busy_secs:.1f} s")
                        proc.busy_secs = 0.0
            if all(p.state in ("exited", "failed") for p in self.procs.values()):
                self._request_stop("every node has exited")
            if deadline is not None and now >= deadline:
                self._request_stop(f"duration of {self.duration_secs:g} s reached")

    def _drain(self) -> None:
        """Before a requested stop, let messages in flight reach their subscribers: wait (at
        most ``DRAIN_SECS``) for a heartbeat of every running node taken after the request
        that shows each edge between them received everything published on it."""
        asked = time.monotonic()
        end = asked + DRAIN_SECS
        while time.monotonic() < end and self._step():
            running = [p for p in self.procs.values() if p.state == "running"]
            stats = {n: p.stats for n, p in self.procs.items() if p.state == "running"}
            if all(p.stats_at > asked for p in running) and balanced(self.local_edges, stats):
                return

    def _shutdown(self) -> None:
        """Stop every node; across hosts a listener (a recorder) fed from another host last:
        once every host has stopped its nodes and it has received all they published."""
        held = [p for n, p in self.procs.items() if n in self.held]
        self._stop([p for p in self.procs.values() if p not in held])
        if self.link is not None:
            published = totals(self.procs)
            self.link.send_final(published)
            if held and self.started_at:  # (not when the hosts never ran together)
                wait_for_finals(self.link, self.edges, published, held, self._step)
        self._stop(held)

    def _step(self) -> bool:
        """Serve and reap once (50 ms at most); whether to go on waiting (no signal came)."""
        self._serve(50)
        self._reap()
        return not self._signals

    def _stop(self, procs: list[Proc]) -> None:
        hurry = bool(self._signals)
        graces = (
            SIGNAL_STOP_GRACE_SECS if hurry else STOP_GRACE_SECS,
            SIGNAL_TERM_GRACE_SECS if hurry else TERM_GRACE_SECS,
        )
        stop(procs, graces, lambda p: self._send(p.spec.name, Stop()), self._step, self.say)
        self._serve(0)

    def run(self) -> int:
        """Start, supervise until something stops the graph, shut down, print the report."""
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            self._open()
            self.say(f"starting {len(self.procs)} node(s) from {self.graph.source}")
            if self._startup():
                self.started_at = time.monotonic()
                self.say("all nodes ready; running")
                self._supervise()
                for proc in nodeprocs.not_back(self.procs.values()):
                    self._ended_badly(proc, f"not back from restart {proc.restarts} at the stop")
            self.say(f"stopping: {self.stop_reason or 'start-up failed'}")
            if self.started_at and self.exit_code == 0:
                self._drain()
            self.stopped_at = time.monotonic()
            self._shutdown()
            self.say(self.report())
        finally:
            self._close()
            for s, handler in old.items():
                signal.signal(s, handler)
        if self._signals and self.exit_code == 0:
            self.exit_code = 128 + self._signals[0]
        return self.exit_code or self.verdict_code

    # -- the end-of-run table ----------------------------------------------------
    def report(self) -> str:
        """Per topic (messages, rate, dropped, superseded, bad, non-finite) and per node."""
        elapsed = (self.stopped_at or time.monotonic()) - (self.started_at or time.monotonic())
        text = table(self.procs, elapsed)
        if self.control.refused:
            text += (
                f"\ncontrol: refused {self.control.refused} message(s) (malformed or not signed)"
            )
        return text
