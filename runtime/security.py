"""ZeroMQ CURVE between hosts: key files, and the ZAP handler that admits only the
graph's keys.

Every host has one CURVE key pair. Its secret key lives in a key file
(``KEYDIR/NAME.key``, mode 0600, in a 0700 folder; default ``~/.config/softbubble/keys``,
``--keys DIR`` elsewhere), never in the graph, which holds only public keys. A socket that
binds tcp on an address that is not loopback is a CURVE server with its host's secret key;
one that connects to such a socket is a CURVE client with its own host's key pair and the
server's public key. Loopback tcp and ipc stay plain.

:class:`Guard` runs in every process that binds such a socket: a ZAP handler on
``inproc://zeromq.zap.01`` that accepts a CURVE peer only if its public key is one of the
graph's (its ``User-Id`` is then that host's name), and a monitor of the bound sockets
that logs a peer refused before ZAP is asked (one speaking plain ZeroMQ to a CURVE
socket). Every refusal is logged with the peer's address and, for CURVE, its key.
"""

from __future__ import annotations

import ipaddress
import math
import os
import socket
import stat
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zmq
import zmq.utils.z85

from messages.errors import GraphError

ZAP_ENDPOINT = "inproc://zeromq.zap.01"
KEY_SUFFIX = ".key"
PUBLIC_SUFFIX = ".pub"
Z85_KEY_CHARS = 40
_HANDSHAKE_ENDS = (
    zmq.EVENT_HANDSHAKE_SUCCEEDED
    | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
    | zmq.EVENT_HANDSHAKE_FAILED_AUTH
    | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
)
_MONITOR_EVENTS = zmq.EVENT_ACCEPTED | zmq.EVENT_DISCONNECTED | _HANDSHAKE_ENDS
# A refused peer usually retries: the first refusal of each (address, reason) is logged,
# then every 100th.
REFUSED_LOG_EVERY = 100
CLOSED_KEEP_SECS = 1.0


def default_key_dir() -> Path:
    config = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(config) / "softbubble" / "keys"


@dataclass(frozen=True)
class KeyPair:
    """One host's CURVE key pair, both keys Z85 text (40 characters)."""

    public: str
    secret: str


def is_public_key(value: Any) -> bool:
    if not isinstance(value, str) or len(value) != Z85_KEY_CHARS:
        return False
    try:
        return len(zmq.utils.z85.decode(value.encode())) == 32
    except (ValueError, KeyError):
        return False


def make_key(key_dir: Path, name: str, *, overwrite: bool = False) -> KeyPair:
    """A new key pair for host ``name``: ``NAME.key`` (0600, both keys) and ``NAME.pub``.

    Raises:
        FileExistsError: the host has a key already and ``overwrite`` is false.
    """
    key_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
    os.chmod(key_dir, 0o700)
    path = key_dir / f"{name}{KEY_SUFFIX}"
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: a key for host {name!r} exists (--overwrite replaces it)")
    public, secret = (k.decode() for k in zmq.curve_keypair())
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(f"public {public}\nsecret {secret}\n")
    (key_dir / f"{name}{PUBLIC_SUFFIX}").write_text(f"{public}\n")
    return KeyPair(public, secret)


def load_key(path: Path) -> KeyPair:
    """Read a key file written by :func:`make_key`, refusing one others can read.

    Raises:
        GraphError: missing, readable by group or others, malformed, or a public key that
            is not the secret key's.
    """
    try:
        mode = path.stat().st_mode
        text = path.read_text()
    except OSError as err:
        raise GraphError(f"{path}: cannot read the host's key file: {err.strerror}") from err
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise GraphError(
            f"{path}: the secret key is readable by others (mode {stat.S_IMODE(mode):04o}); "
            f"chmod 600 {path}"
        )
    fields = dict(line.split(" ", 1) for line in text.splitlines() if " " in line)
    public, secret = fields.get("public", ""), fields.get("secret", "")
    if not (is_public_key(public) and is_public_key(secret)):
        raise GraphError(f"{path}: not a key file (expected 'public KEY' and 'secret KEY' lines)")
    if zmq.curve_public(secret.encode()).decode() != public:
        raise GraphError(f"{path}: its public key is not its secret key's")
    return KeyPair(public, secret)


def list_keys(key_dir: Path) -> list[tuple[str, str, bool]]:
    """``(host, public key, has secret)`` for every key in ``key_dir``, by name."""
    rows = []
    for pub in sorted(key_dir.glob(f"*{PUBLIC_SUFFIX}")):
        name = pub.name.removesuffix(PUBLIC_SUFFIX)
        rows.append((name, pub.read_text().strip(), (key_dir / f"{name}{KEY_SUFFIX}").exists()))
    return rows


def needs_curve(endpoint: str) -> bool:
    """Whether ``endpoint`` is tcp on an address that is not loopback."""
    if not endpoint.startswith("tcp://"):
        return False
    host = endpoint.removeprefix("tcp://").rpartition(":")[0].strip("[]")
    try:
        return not ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host != "localhost"


def serve(sock: zmq.Socket[Any], keys: KeyPair) -> None:
    """Make ``sock`` a CURVE server (before it binds)."""
    sock.curve_server = True
    sock.curve_secretkey = keys.secret.encode()
    sock.curve_publickey = keys.public.encode()
    sock.zap_domain = b"softbubble"


def connect_to(sock: zmq.Socket[Any], keys: KeyPair, server_public: str) -> None:
    """Make ``sock`` a CURVE client of the server with ``server_public`` (before it connects)."""
    sock.curve_serverkey = server_public.encode()
    sock.curve_publickey = keys.public.encode()
    sock.curve_secretkey = keys.secret.encode()


class Guard:
    """ZAP for one context (only ``authorized`` keys: public key -> host name), and the
    log of peers refused before ZAP, on the sockets given to :meth:`watch`."""

    def __init__(
        self, ctx: zmq.Context[Any], authorized: Mapping[str, str], log: Callable[[str], None]
    ) -> None:
        self.authorized = dict(authorized)
        self.log = log
        self.refused = 0
        self.counts: dict[tuple[str, str], int] = {}
        self.ctx = ctx
        self.zap = ctx.socket(zmq.REP)
        self.zap.setsockopt(zmq.LINGER, 0)
        self.zap.bind(ZAP_ENDPOINT)
        self.monitors: list[zmq.Socket[Any]] = []
        self.guarded: list[zmq.Socket[Any]] = []
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def watch(self, sock: zmq.Socket[Any]) -> None:
        """Log peers ``sock`` refuses for speaking plain ZeroMQ (call before :meth:`start`)."""
        address = f"inproc://guard.monitor.{id(sock)}"
        sock.monitor(address, _MONITOR_EVENTS)
        mon = self.ctx.socket(zmq.PAIR)
        mon.setsockopt(zmq.LINGER, 0)
        mon.connect(address)
        self.monitors.append(mon)
        self.guarded.append(sock)

    def start(self) -> None:
        self.thread.start()

    def close(self) -> None:
        """Stop answering: only once the sockets given to :meth:`watch` are closed. A
        connection whose CURVE handshake reaches ZAP after this never ends, and libzmq
        (4.3.5) then never finishes closing its socket, whose port stays bound."""
        if any(not sock.closed for sock in self.guarded):
            raise RuntimeError("Guard.close: close the sockets it guards first")
        self.stopping.set()
        if self.thread.is_alive():
            self.thread.join(timeout=2)
        for sock in (self.zap, *self.monitors):
            sock.close(linger=0)

    def _refuse(self, address: str, why: str) -> None:
        self.refused += 1
        key = (address, why)
        count = self.counts[key] = self.counts.get(key, 0) + 1
        if count == 1 or count % REFUSED_LOG_EVERY == 0:
            self.log(f"refused a peer at {address} ({count} time(s)): {why}")

    def _run(self) -> None:
        poller = zmq.Poller()
        poller.register(self.zap, zmq.POLLIN)
        for mon in self.monitors:
            poller.register(mon, zmq.POLLIN)
        # Accepted connections whose handshake has not ended, oldest first: a handshake
        # event names no connection, and they end in the order they began.
        # A connection may be reported closed just before its failed handshake: kept
        # (with the time it closed) for CLOSED_KEEP_SECS.
        pending: dict[int, tuple[str, float]] = {}
        # Here, not at the top: it imports asyncio (30 ms of every node's start).
        from zmq.utils.monitor import recv_monitor_message

        while not self.stopping.is_set():
            try:
                ready = poller.poll(200)
            except zmq.ContextTerminated:
                return
            for sock, _ in ready:
                if sock is self.zap:
                    self._answer(self.zap.recv_multipart())
                    continue
                event = recv_monitor_message(sock)
                kind, value = event["event"], event["value"]
                if kind == zmq.EVENT_ACCEPTED:
                    pending.pop(value, None)  # a number the OS gave again: now the newest
                    pending[value] = (_peer_of(value), math.inf)
                elif kind == zmq.EVENT_DISCONNECTED:
                    if value in pending:
                        pending[value] = (pending[value][0], time.monotonic())
                    now = time.monotonic()
                    for old in [f for f, (_, at) in pending.items() if now - at > CLOSED_KEEP_SECS]:
                        del pending[old]
                elif kind & _HANDSHAKE_ENDS:
                    first = next(iter(pending), None)
                    peer = "an unknown address" if first is None else pending.pop(first)[0]
                    peer = peer.rpartition(":")[0] or peer
                    if kind == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL:
                        self._refuse(peer, _handshake_error(value))
                    elif kind == zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL:  # ZAP logs a bad key
                        why = os.strerror(value) if value > 0 else "no detail"
                        self._refuse(
                            peer, f"the handshake failed ({why}): not CURVE with a graph key"
                        )

    def _answer(self, frames: list[bytes]) -> None:
        """One ZAP request (RFC 27): accept an authorized CURVE key, refuse anything else."""
        version, request_id, _domain, address, _identity, mechanism = frames[:6]
        credentials = frames[6:]
        peer = address.decode(errors="replace")
        status, text, user = b"400", b"not authorized", b""
        if mechanism == b"CURVE" and credentials:
            key = zmq.utils.z85.encode(credentials[0]).decode()
            host = self.authorized.get(key)
            if host is not None:
                status, text, user = b"200", b"OK", host.encode()
            else:
                self._refuse(peer, f"CURVE key {key} is not one of the graph's hosts")
        else:
            self._refuse(peer, f"mechanism {mechanism.decode(errors='replace')}, not CURVE")
        self.zap.send_multipart([version, request_id, status, text, user, b""])


def _peer_of(fd: int) -> str:
    """The address at the other end of the connection numbered ``fd``, for the log. By the
    time the monitor's event is read the connection may be gone and its number reused:
    by no socket, or a local one (whose peer is no address and port)."""
    try:
        with socket.fromfd(fd, socket.AF_INET, socket.SOCK_STREAM) as s:
            peer = s.getpeername()
    except OSError:
        return "an unknown address"
    if not isinstance(peer, tuple):  # a Unix socket's peer: a path, or '' when unnamed
        return "an unknown address"
    return f"{peer[0]}:{peer[1]}"


def _handshake_error(code: int) -> str:
    if code == zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH:
        return "it speaks plain ZeroMQ to a CURVE socket (mechanism mismatch)"
    return f"handshake failed (ZeroMQ protocol error {code:#x})"
