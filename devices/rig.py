"""A whole rig's devices, connected in one place: two pressure sensors, two cameras, the gripper.

What a calibration (``launch.py calibrate``) needs open at once, outside a graph:
:func:`connect` opens each device by its serial, id and address and returns a
:class:`RigDevices` whose :meth:`~RigDevices.close` closes what was opened (also when a
later device failed to open, in which case the :class:`DeviceError` names that device).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from contextlib import ExitStack
from dataclasses import dataclass, field

from devices import mcp2221
from devices.abp import AbpSensor
from devices.royale import RoyaleCamera
from devices.wsg50_client import WSG50Client


@dataclass
class RigDevices:
    """Per side an ABP sensor and a camera; the gripper client; what closes them."""

    sensors: dict[str, AbpSensor]
    cameras: dict[str, RoyaleCamera]
    gripper: WSG50Client
    _stack: ExitStack = field(default_factory=ExitStack)

    def close(self) -> None:
        self._stack.close()


def connect(
    *,
    bridges: Mapping[str, str],
    cameras: Mapping[str, str],
    address: tuple[str, int],
    use_case: str,
    on_event: Callable[[str], None] | None = None,
) -> RigDevices:
    """Open every device (bridge serials and camera ids per side, the WSG 50's address).

    Raises:
        DeviceError: a device could not be opened (those already open are closed).
    """
    with ExitStack() as stack:
        backend = mcp2221.default_backend()
        sensors = {}
        for side, serial in bridges.items():
            bridge = mcp2221.MCP2221(serial, backend=backend)
            bridge.connect()
            stack.callback(bridge.disconnect)
            sensors[side] = AbpSensor(bridge)
        opened = {}
        for side, camera_id in cameras.items():
            camera = RoyaleCamera(camera_id, use_case=use_case)
            camera.connect()
            stack.callback(camera.disconnect)
            opened[side] = camera
        gripper = WSG50Client(*address, on_event=on_event)
        gripper.connect()
        stack.callback(gripper.disconnect)
        rig = RigDevices(sensors, opened, gripper)
        rig._stack = stack.pop_all()
        return rig
