"""MCAP bags: record the graph's messages, read them back with or without today's classes.

A bag is an ordinary MCAP file (any MCAP reader lists and reads it):

- one **channel per topic** (``message_encoding`` ``"msgpack"``), metadata ``type``,
  ``fingerprint`` and ``packing``;
- one **schema per message type and fingerprint** (JSON, :mod:`runtime.bag.schema`): the
  type's description at record time and, field by field, what a reader in another
  language needs (types with widths, units, dtype, byte and memory order, special values);
- each **message** is ONE MessagePack value (:mod:`runtime.bag.packing`): a map of the
  wire header's fields and each array as ``bin`` with its dtype, shape and order; MCAP
  ``log_time`` is the recorder's receive time, ``publish_time`` the message's
  ``header.stamp_nanos`` and ``sequence`` its ``header.seq``;
- **metadata records**: ``softbubble.run`` (graph text and path, command line, start time,
  host), ``softbubble.channel`` (a copy of each channel and its schema outside the chunks)
  and ``softbubble.drops`` (per-topic drops, rewritten at every flush; the last one wins).

Writing: :mod:`runtime.bag.writer`. Reading, also of damaged files and of bags recorded
in the older multipart packing: :mod:`runtime.bag.reader` and :mod:`runtime.bag.scan`.
"""

from __future__ import annotations

import re
from collections.abc import Callable

from runtime.bag.message import BagMessage
from runtime.bag.packing import PACKING, PACKING_V1
from runtime.bag.reader import MAGIC, BagReader, TopicStats
from runtime.bag.schema import SCHEMA_ENCODING, ChannelInfo, TopicSchema, schema_for
from runtime.bag.writer import MESSAGE_ENCODING, BagWriter, TopicCounts

__all__ = [
    "MAGIC",
    "MESSAGE_ENCODING",
    "PACKING",
    "PACKING_V1",
    "SCHEMA_ENCODING",
    "BagMessage",
    "BagReader",
    "BagWriter",
    "ChannelInfo",
    "TopicCounts",
    "TopicSchema",
    "TopicStats",
    "schema_for",
    "topic_filter",
]


def topic_filter(pattern: str | None) -> Callable[[str], bool]:
    """A predicate for topics matching ``pattern`` (``re.search``, as ``launch.py --topics``
    selects what to record; anchor it with ``^...$`` for exact names; ``None`` = all).

    Raises:
        ValueError: the pattern is not a valid regular expression.
    """
    if not pattern:
        return lambda topic: True
    try:
        regex = re.compile(pattern)
    except re.error as err:
        raise ValueError(f"topics: bad regular expression {pattern!r}: {err}") from err
    return lambda topic: regex.search(topic) is not None
