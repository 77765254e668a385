"""A rogue local client on the launcher's control socket: refused, counted, never fatal."""

from __future__ import annotations

import time
from pathlib import Path

import msgpack
import zmq

from runtime.protocol import MAX_CONTROL_BYTES
from tests.faults.conftest import sink, ticker


def control_endpoint(tmpdir) -> str:
    end = time.monotonic() + 30
    while time.monotonic() < end:
        found = sorted(tmpdir.glob("sbg-*/control"))
        if found:
            return f"ipc://{found[0]}"
        time.sleep(0.02)
    raise AssertionError("no control socket in the run folder")


def forge(endpoint: str, identity: bytes, *parts: bytes) -> None:
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.IDENTITY, identity)
    sock.setsockopt(zmq.LINGER, 500)
    sock.connect(endpoint)
    sock.send_multipart(list(parts))
    sock.close()


def pack(**body) -> bytes:
    return msgpack.packb(body, use_bin_type=True)


FORGERIES = [
    (b"\xff\xfe\x00", [b"not msgpack"]),  # a non-UTF-8 identity
    (b"a", [b"\xc1\xc1\xc1"]),  # a non-msgpack payload
    (b"a", [pack(kind="heartbeat", busy_secs=0.0, stats={}), b"second part"]),
    (b"a", [b"one", b"two", b"three"]),
    (b"a", [b""]),
    (b"a", [msgpack.packb([1, 2, 3])]),  # not a map
    (b"a", [pack(kind=5)]),
    (b"a#hb", [pack(kind="heartbeat", busy_secs="long", stats=7)]),  # wrong types
    (b"a", [pack(kind="hello")]),  # a field missing
    # Well-formed but without the run's secret: a forged hang and a forged stop.
    (b"a#hb", [pack(kind="heartbeat", busy_secs=1e9, stats={})]),
    (b"a", [pack(kind="stop_request", reason="forged")]),
    (b"b", [pack(kind="final", stats={})]),
]


def test_forged_and_malformed_control_messages_are_refused(run) -> None:
    r = run({"a": ticker(rate_hz=50.0), "b": sink("a/tick")}, "--duration", "4")
    endpoint = control_endpoint(r.tmpdir)
    r.wait_for("all nodes ready")
    for i, (identity, parts) in enumerate(FORGERIES):
        # A ROUTER refuses a second peer with an identity in use: make each one unique
        # (the part after '#' named the heartbeat socket; the node is the part before).
        forge(endpoint, identity + f"#{i}".encode(), *parts)
    code = r.finish(timeout=60)
    log = r.log
    assert code == 0, log
    assert "Traceback" not in log, log
    assert "stopping: duration of 4 s reached" in log
    assert "asks to stop" not in log and "killed" not in log, log
    assert f"control: refused {len(FORGERIES)} message(s)" in log, log
    assert r.leftovers() == ([], []), log


def test_a_non_loopback_host_is_refused_without_encryption(run) -> None:
    a = ticker()
    a["host"] = "0.0.0.0"
    r = run({"a": a, "b": sink("a/tick")})
    code = r.finish(timeout=60)
    assert code == 2, r.log
    assert "'0.0.0.0'" in r.log and "loopback" in r.log, r.log
    assert "starting" not in r.log
    assert r.leftovers() == ([], []), r.log


def peak_rss_kb(pid: int) -> int:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(next(ln for ln in status.splitlines() if ln.startswith("VmHWM:")).split()[1])


def test_an_oversized_frame_is_refused_before_it_is_read(run) -> None:
    r = run({"a": ticker(rate_hz=50.0), "b": sink("a/tick")}, "--duration", "4")
    endpoint = control_endpoint(r.tmpdir)
    r.wait_for("all nodes ready")
    before = peak_rss_kb(r.proc.pid)
    big = MAX_CONTROL_BYTES * 64  # 64 MiB: read whole, the launcher would hold it all
    forge(endpoint, b"a#big", b"\0" * big, b"tag")
    time.sleep(1.0)
    grew = peak_rss_kb(r.proc.pid) - before
    code = r.finish(timeout=60)
    assert code == 0, r.log
    assert grew < big // 1024 // 4, f"the launcher's peak memory grew by {grew} kB\n{r.log}"
    assert "stopping: duration of 4 s reached" in r.log
    assert r.leftovers() == ([], []), r.log
