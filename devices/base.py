"""What every device client shares: its lifecycle (connect, disconnect, is_connected)."""

from __future__ import annotations

import abc
from typing import Self


class Device(abc.ABC):
    """A client of one piece of hardware (or its emulator).

    :meth:`connect` opens it (raising :class:`messages.errors.DeviceError` with what to
    check), :meth:`disconnect` lets it go (safe to call when it is gone, or twice), and
    :attr:`is_connected` says which of the two was last. As a context manager a device is
    connected inside the ``with`` block and disconnected however the block ends.
    """

    @property
    @abc.abstractmethod
    def is_connected(self) -> bool:
        """Whether :meth:`connect` succeeded and :meth:`disconnect` has not run since."""

    @abc.abstractmethod
    def connect(self) -> None:
        """Open the device (raises ``DeviceError``)."""

    @abc.abstractmethod
    def disconnect(self) -> None:
        """Let the device go; nothing to do once it is gone."""

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()
