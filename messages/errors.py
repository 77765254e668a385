"""The project's error hierarchy, in one place.

Every layer raises these (or plain ``ValueError`` for bad arguments in the pure
libraries), so callers can catch one family. Messages start with the name of the
thing at fault (file, node, field, topic) so a log line is enough to act on.
"""

from __future__ import annotations


class SoftbubbleError(Exception):
    """Base of every error this project raises on purpose."""


class FrameDecodeError(SoftbubbleError):
    """A frame could not be decoded: truncated, wrong buffer size, unknown type, bad dtype."""


class FingerprintMismatchError(FrameDecodeError):
    """The frame's schema fingerprint differs from the receiver's declaration of that type."""


class GraphError(SoftbubbleError):
    """The graph file is invalid; nothing was started."""


class NodeError(SoftbubbleError):
    """A node failed at run time (setup, handler, parameters)."""


class DeviceError(SoftbubbleError):
    """A hardware driver (or its emulator) reported a fault or broke protocol."""


class BagError(SoftbubbleError):
    """A bag file could not be read or written."""


class SchemaChangeError(FingerprintMismatchError):
    """A stored message's declaration of its type cannot be read as today's declaration."""
