"""How a message's bytes sit in a bag's MCAP message record (the channel's ``packing``).

``softbubble-msgpack-v2`` (written today): ONE MessagePack value per message, the map that
:func:`messages.codec.pack_single` makes (fields as on the wire, each array as ``bin``
with its dtype, shape and order beside it). Any MessagePack library reads it whole.

``softbubble-multipart-v1`` (bags recorded before): the multipart frame minus the topic,
behind a frame table. Read-only here, so old bags stay readable::

    u32 LE   n                     number of frames that follow (header + one per array)
    n x u64 LE                     byte length of each frame
    frame 1  MessagePack header    exactly as on the wire
    frame 2+ raw array buffers     exactly as on the wire
"""

from __future__ import annotations

import struct
from typing import Any

from messages.codec import unpack_single
from messages.errors import FrameDecodeError

PACKING = "softbubble-msgpack-v2"
PACKING_V1 = "softbubble-multipart-v1"


def unpack_multipart(payload: bytes | memoryview) -> list[memoryview]:
    """Split a ``softbubble-multipart-v1`` payload into ``[header, *buffers]`` views (no copy).

    Raises:
        ValueError: the payload is shorter or longer than its frame table says.
    """
    view = memoryview(payload)
    if view.nbytes < 4:
        raise ValueError(f"payload of {view.nbytes} bytes has no frame count")
    (count,) = struct.unpack_from("<I", view, 0)
    table_end = 4 + 8 * count
    if count == 0 or table_end > view.nbytes:
        raise ValueError(f"payload of {view.nbytes} bytes cannot hold {count} frames")
    lengths = struct.unpack_from(f"<{count}Q", view, 4)
    if table_end + sum(lengths) != view.nbytes:
        raise ValueError(
            f"payload of {view.nbytes} bytes, its frame table adds up to {table_end + sum(lengths)}"
        )
    frames = []
    pos = table_end
    for length in lengths:
        frames.append(view[pos : pos + length])
        pos += length
    return frames


def unpack(payload: bytes | memoryview, packing: str) -> list[Any]:
    """``[header, *buffers]`` of a stored message, whichever its packing.

    Raises:
        FrameDecodeError: the payload is not a message of that packing.
    """
    if packing == PACKING_V1:
        try:
            return unpack_multipart(payload)
        except ValueError as err:
            raise FrameDecodeError(str(err)) from err
    if packing != PACKING:
        raise FrameDecodeError(f"unknown packing {packing!r}")
    return unpack_single(payload)
