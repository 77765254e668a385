"""One lifecycle for every device client: connect, disconnect, is_connected, ``with``."""

from __future__ import annotations

import inspect

import pytest

from devices.base import Device
from devices.mcp2221 import MCP2221
from devices.royale import RoyaleCamera
from devices.wsg50_client import WSG50Client
from messages.errors import DeviceError


@pytest.mark.parametrize("cls", [MCP2221, RoyaleCamera, WSG50Client], ids=lambda c: c.__name__)
def test_every_client_is_a_complete_device(cls: type[Device]) -> None:
    assert issubclass(cls, Device) and not inspect.isabstract(cls)
    assert isinstance(inspect.getattr_static(cls, "is_connected"), property)


class Flaky(Device):
    """A device whose connect can fail, counting what the base calls."""

    def __init__(self, fail: bool = False) -> None:
        self.fail = fail
        self.calls: list[str] = []
        self._open = False

    @property
    def is_connected(self) -> bool:
        return self._open

    def connect(self) -> None:
        self.calls.append("connect")
        if self.fail:
            raise DeviceError("flaky: not plugged in")
        self._open = True

    def disconnect(self) -> None:
        self.calls.append("disconnect")
        self._open = False


def test_with_connects_and_disconnects_even_when_the_block_fails() -> None:
    device = Flaky()
    with pytest.raises(RuntimeError, match="boom"), device as same:
        assert same is device and device.is_connected
        raise RuntimeError("boom")
    assert device.calls == ["connect", "disconnect"] and not device.is_connected


def test_a_failed_connect_leaves_nothing_to_disconnect() -> None:
    device = Flaky(fail=True)
    with pytest.raises(DeviceError, match="not plugged in"), device:
        pytest.fail("the block runs only on a connected device")
    assert device.calls == ["connect"] and not device.is_connected


def test_a_client_without_the_lifecycle_cannot_be_made() -> None:
    class Half(Device):
        def connect(self) -> None:
            pass

    with pytest.raises(TypeError, match="abstract"):
        Half()  # type: ignore[abstract]
