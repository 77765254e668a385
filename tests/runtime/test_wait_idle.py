"""A node waiting at a lockstep barrier still hears a stop (a signal, its launcher's death)."""

from __future__ import annotations

import threading

import pytest
import zmq

from runtime.zmqio import ZmqIO


@pytest.mark.timeout(60)
def test_a_stop_requested_while_waiting_for_idle_ends_the_wait(tmp_path) -> None:
    """The launcher never answers (it died); the node's SIGTERM handler sets
    ``stop_requested``: the wait ends then, not after its idle timeout (an hour here; the
    replay's default is 60 s, which orphaned replay nodes outlived their launcher by)."""
    ctx = zmq.Context()
    launcher = ctx.socket(zmq.ROUTER)
    launcher.bind(f"ipc://{tmp_path}/control")
    spec = {
        "name": "replay",
        "outputs": {},
        "lockstep": True,
        "bind": f"ipc://{tmp_path}/pub",
        "secret": "00" * 32,
        "control": f"ipc://{tmp_path}/control",
    }
    io = ZmqIO(spec, ctx)

    def stop_once_waiting() -> None:
        launcher.recv_multipart()  # the counts
        launcher.recv_multipart()  # the wait: the node is in wait_idle now
        io.stop_requested = True  # what runtime.runner's signal handler does

    stopper = threading.Thread(target=stop_once_waiting)
    stopper.start()
    try:
        assert io.wait_idle(3600.0) is False
        assert not io.waiting
    finally:
        stopper.join(timeout=10)
        io.pub.close(0)
        io.control.close(0)
        launcher.close(0)
        ctx.term()
