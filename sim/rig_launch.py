"""``--emulate``: a hardware graph, unchanged but for where its devices are, on an emulated rig.

:func:`emulate` takes a graph document (the plain dict of ``runtime.graphfile``) whose
nodes drive real devices (``gripper.wsg50``, ``bubble_camera.royale``, ``pressure.usb``)
and returns it with

* a world node added (``rig_world``: ``world.sim`` on the rig's scene) that serves the
  WSG 50 protocol on a free loopback port and publishes its states on the rig's feed;
* only the device addresses changed: the gripper's address and port point at that
  emulator, each camera's ``camera_id`` and each bridge's ``serial`` at the as-built
  rig's emulated devices (``sim.emulated_rig``).

:func:`activate` prepares this process (and the node processes it starts) for the
emulators: it writes the session file, names the USB backend, and puts the royale SDK
stand-in (``sim/royale_sdk``) on the import path as a lab puts the SDK's ``python``
folder there. Nothing else of the graph changes: same node implementations, same
parameters, same wiring.
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import socket
import sys
import tempfile
from pathlib import Path
from typing import Any

from devices.mcp2221 import BACKEND_ENV
from sim.emulated_rig import NOMINAL, SESSION_ENV, AsBuiltRig, forget_session, load_rig

ROYALE_STANDIN = Path(__file__).resolve().parent / "royale_sdk"
USB_BACKEND = "sim.emulated_rig:usb_backend"
DEFAULT_SCENE = str(Path(__file__).resolve().parent.parent / "scenes" / "rig_handover.yaml")
WORLD = "rig_world"
DEVICE_IMPLS = ("gripper.wsg50", "bubble_camera.royale", "pressure.usb")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def emulate(
    doc: dict[str, Any], *, rig: AsBuiltRig = NOMINAL, scene: str = DEFAULT_SCENE, feed: str
) -> dict[str, Any]:
    """``doc`` rewired to the emulated rig (see the module docstring); raises ``ValueError``
    naming the graph's problem when it drives no device this rig emulates."""
    nodes = doc.get("nodes")
    if not isinstance(nodes, dict):
        raise ValueError("--emulate: the graph has no `nodes` mapping")
    if WORLD in nodes:
        raise ValueError(f"--emulate: the graph already has a node named {WORLD!r}")
    devices = {
        name: spec
        for name, spec in nodes.items()
        if isinstance(spec, dict) and spec.get("impl") in DEVICE_IMPLS
    }
    if not devices:
        raise ValueError(
            f"--emulate: no node drives a device ({', '.join(DEVICE_IMPLS)}): nothing to emulate"
        )
    port = free_port()
    for name, spec in devices.items():
        params = spec.setdefault("params", {})
        side = params.get("sensor", "")
        if spec["impl"] == "gripper.wsg50":
            params.update(address="127.0.0.1", port=port)
        elif side not in rig.cameras:
            raise ValueError(f"--emulate: node {name!r} has no `sensor: left|right`")
        elif spec["impl"] == "bubble_camera.royale":
            params["camera_id"] = rig.cameras[side].camera_id
        else:
            params["serial"] = rig.pressure[side].serial
    nodes[WORLD] = {
        "impl": "world.sim",
        "params": {"scene": scene, "wsg50_port": port, "rig_feed": feed},
    }
    return doc


def activate(rig_file: str | None, scene: str = DEFAULT_SCENE) -> tuple[AsBuiltRig, str, Path]:
    """Set up this process for an emulated rig: ``(rig, feed endpoint, session folder)``.

    The session folder holds the session file, the feed's socket and the plugs
    (``unplugged/<device>``); it is removed when this process exits.
    """
    rig = load_rig(rig_file) if rig_file else NOMINAL
    folder = Path(tempfile.mkdtemp(prefix="softbubble-rig-"))
    owner = os.getpid()

    def remove() -> None:  # forks (the nodes) inherit the handler: only this process removes it
        if os.getpid() == owner:
            shutil.rmtree(folder, ignore_errors=True)

    atexit.register(remove)
    forget_session()
    (folder / "unplugged").mkdir()
    feed = f"ipc://{folder / 'feed'}"
    session = {
        "scene": str(Path(scene).resolve()),
        "feed": feed,
        "rig": str(Path(rig_file).resolve()) if rig_file else "",
        "plugs": str(folder),
    }
    (folder / "session.json").write_text(json.dumps(session))
    os.environ[SESSION_ENV] = str(folder / "session.json")
    os.environ[BACKEND_ENV] = USB_BACKEND
    path = os.environ.get("PYTHONPATH", "")
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROYALE_STANDIN), path) if p)
    if str(ROYALE_STANDIN) not in sys.path:
        sys.path.insert(0, str(ROYALE_STANDIN))  # the forked nodes inherit it
    return rig, feed, folder
