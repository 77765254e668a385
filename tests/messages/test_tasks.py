"""Typed task events: every record a TaskEvent carries survives the wire and a bag, typed;
a bag recorded when the figures were JSON text in ``detail`` still decodes; an event
name or record kind nobody declared is refused, naming the field."""

from __future__ import annotations

from typing import Any

import msgpack
import pytest

from messages import FrameDecodeError, Header, TaskEvent, decode, encode
from messages.base import fingerprint_of
from messages.codec import pack_single, unpack_single
from messages.tasks import (
    GraspRef,
    GraspSkipped,
    GraspStart,
    GraspSummary,
    GraspWritten,
    JoltRecord,
    LoadingSummary,
    ObjectOutcome,
    PlacementSummary,
    RunEnd,
    RunStart,
    SortChoice,
    Spread,
    TaskData,
    TaskEventName,
    TrackingSummary,
)
from tests.messages.declare import declare

RECORDS: dict[str, tuple[TaskEventName, TaskData]] = {
    "grasp summary": (
        "summary",
        GraspSummary(
            held_secs=1.25,
            pose_statuses={"ok": 3, "suspect": 1},
            release="pet_bottle (0.912) placed in recycling",
            sorted=SortChoice(class_name="pet_bottle", confidence=0.912, bin="recycling"),
        ),
    ),
    "never held": (
        "summary",
        GraspSummary(held_secs=None, pose_statuses={}, release=""),
    ),
    "placement": (
        "summary",
        PlacementSummary(
            release_secs=2.5,
            outcome="placed",
            t_secs=3.0,
            touch_secs=None,
            gap_mm=0.0,
            push_mm=1.5,
            tilt_deg=0.25,
        ),
    ),
    "tracking": (
        "summary",
        TrackingSummary(
            estimates=120,
            unmatched=0,
            axis_deg=Spread(median=0.1, p95=0.5, max=8.0),
            offaxis_mm=Spread(median=0.2, p95=0.9, max=3.0),
            statuses={"ok": 118, "recovered": 2},
            jolts=[JoltRecord(t_secs=1.0, moved_mm=3.0, turned_deg=8.0, reacquire_secs=None)],
            success=False,
        ),
    ),
    "object": (
        "object",
        ObjectOutcome(index=2, object="mug", true_class="mug", predicted="mug", right=True),
    ),
    "loading": (
        "summary",
        LoadingSummary(
            objects=4,
            right=3,
            wrong=1,
            manual=0,
            regrasps=2,
            task_secs=61.5,
            objects_per_minute=3.9,
        ),  # fmt: skip
    ),
    "run start": (
        "run_start",
        RunStart(seeds={"autolabel": 2}, scene={"generator": {"seed": 2, "objects": ["mug"]}}),
    ),
    "run end": ("run_end", RunEnd(finished=3, failed=1)),
    "grasp start": ("grasp_start", GraspStart(grasp_id=4, params={"class_label": "mug"})),
    "grasp end": ("grasp_end", GraspRef(grasp_id=4)),
    "written": ("grasp_written", GraspWritten(grasp_id=4, frames=10, object_class="mug")),
    "skipped": ("grasp_skipped", GraspSkipped(grasp_id=5, labels={"mug": 2, "wine_glass": 1})),
}


def _event(event: TaskEventName, data: TaskData | None) -> TaskEvent:
    return TaskEvent(
        header=Header(stamp_nanos=7, seq=1), task="sort", event=event, detail="d", data=data
    )


@pytest.mark.parametrize("case", sorted(RECORDS))
def test_every_record_round_trips_typed_on_the_wire_and_in_a_bag(case: str) -> None:
    event, data = RECORDS[case]
    frames = encode("supervisor/event", _event(event, data))
    _, live = decode(frames, expect=TaskEvent)
    _, stored = decode([frames[0], *unpack_single(pack_single(frames[1:]))], expect=TaskEvent)
    for msg in (live, stored):
        assert isinstance(msg, TaskEvent) and msg.event == event
        assert type(msg.data) is type(data) and msg.data == data
    # On the wire a record is a map that names its kind: plain MessagePack reads it.
    fields = msgpack.unpackb(bytes(frames[1]))["fields"]
    assert fields["data"]["kind"] == type(data).__struct_config__.tag


def test_an_event_without_a_record_round_trips() -> None:
    _, msg = decode(encode("supervisor/event", _event("grasping", None)))
    assert isinstance(msg, TaskEvent) and msg.data is None and msg.detail == "d"


def _header(fields: dict[str, Any], fp: str | None = None) -> bytes:
    return msgpack.packb(
        {"type": "TaskEvent", "fp": fp or TaskEvent.schema().fingerprint, "fields": fields,
         "arrays": []}
    )  # fmt: skip


REFUSED: dict[str, dict[str, Any]] = {
    "event nobody declared": {"event": "exploded"},
    "record of no declared kind": {"data": {"kind": "mystery", "grasp_id": 1}},
    "record without its kind": {"data": {"grasp_id": 1}},
    "record missing a field": {"data": {"kind": "grasp_written", "grasp_id": 1}},
    "field of the wrong type": {"data": {"kind": "grasp", "grasp_id": "four"}},
}


@pytest.mark.parametrize("case", sorted(REFUSED))
def test_a_bad_event_or_record_is_refused_naming_the_field(case: str) -> None:
    fields = {
        "header": {"stamp_nanos": 0, "seq": 0, "frame_id": ""},
        "task": "sort",
        "event": "summary",
        "detail": "",
        "data": None,
        **REFUSED[case],
    }
    with pytest.raises(FrameDecodeError, match=r"TaskEvent: .*\$\.(event|data)"):
        decode([b"supervisor/event", _header(fields)], expect=TaskEvent)


def test_a_bag_of_json_details_still_decodes(scratch_registry: dict) -> None:
    """Recorded when ``event`` was any string and the figures JSON text in ``detail``."""
    del scratch_registry["TaskEvent"]
    old = declare(
        "TaskEvent", [("header", Header), ("task", str), ("event", str), ("detail", str, "")]
    )
    scratch_registry["TaskEvent"] = TaskEvent
    description = old.schema().description
    fields = {
        "header": {"stamp_nanos": 5, "seq": 2, "frame_id": ""},
        "task": "stacking",
        "event": "summary",
        "detail": '{"gap_mm": 0.0, "outcome": "placed", "push_mm": 1.5}',
    }
    frames = [b"supervisor/event", _header(fields, fingerprint_of(description))]
    _, msg = decode(frames, stored=description)
    assert isinstance(msg, TaskEvent) and msg.event == "summary" and msg.data is None
    assert msg.detail == fields["detail"]  # kept as it was recorded
    # An old event name outside today's choices is refused, naming the field.
    fields["event"] = "exploded"
    frames = [b"supervisor/event", _header(fields, fingerprint_of(description))]
    with pytest.raises(FrameDecodeError, match=r"\$\.event"):
        decode(frames, stored=description)
