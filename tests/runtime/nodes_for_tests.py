"""Node classes used only by the runtime tests (named as ``module:Class`` in graphs)."""

from __future__ import annotations

import random
from typing import Annotated

import msgspec
from msgspec import Meta

from messages import Header, Pressure, Tick, encode
from messages.base import Message
from runtime.node import Node
from runtime.params import ExistingFile


class PressureSource(Node):
    """Publishes a Pressure message: a type that does not fit a Tick input."""

    outputs = {"pressure": Pressure}


class FuzzParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    count: int = 50
    seed: int = 0


class Fuzzer(Node):
    """Interleaves valid ticks with random bytes and mutated frames on its one topic."""

    Params = FuzzParams
    outputs = {"tick": Tick}

    def setup(self) -> None:
        self.rng = random.Random(self.params.seed)
        self.sent = 0
        self.io.add_timer(0.005, self.tick)

    def _garbage(self, topic: str) -> list[bytes]:
        valid = [bytes(f) for f in encode(topic, Tick(header=Header(seq=self.sent), value=-1.0))]
        choice = self.rng.randrange(6)
        if choice == 0:
            return [topic.encode(), self.rng.randbytes(self.rng.randrange(1, 64))]
        if choice == 1:  # truncated: header only, the array buffer missing
            return valid[:2]
        if choice == 2:  # a flipped byte in the header
            header = bytearray(valid[1])
            header[self.rng.randrange(len(header))] ^= 0xFF
            return [valid[0], bytes(header), *valid[2:]]
        if choice == 3:  # wrong buffer size
            return [valid[0], valid[1], b"\x00" * 7]
        if choice == 4:  # an extra frame
            return [*valid, b"extra"]
        return [valid[0]]  # topic only

    def tick(self) -> None:
        if self.sent >= self.params.count:
            return
        topic = f"{self.name}/tick"
        self.io.publish_raw(topic, self._garbage(topic))
        self.io.publish(
            "tick", Tick(header=Header(stamp_nanos=self.io.now_nanos()), value=float(self.sent))
        )
        self.sent += 1
        if self.sent == self.params.count:
            self.io.request_stop("fuzzing done")


class InnerParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    winsize: Annotated[int, Meta(ge=3, le=201)] = 15


class NestedParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Nested parameters and a file that must exist, as the graph checker sees them."""

    inner: Annotated[InnerParams, Meta(description="the nested knobs")] = msgspec.field(
        default_factory=InnerParams
    )
    tol: Annotated[float, Meta(gt=0, description="a solver tolerance.")] = 1e-6
    model: Annotated[ExistingFile, Meta(description="a file read at start.")] = __file__


class NestedNode(Node):
    """A relay whose parameters nest (``inner.winsize``) and name a file (``model``)."""

    Params = NestedParams
    inputs = {"tick": Tick}
    outputs = {"tick": Tick}

    def on_tick(self, msg: Tick) -> None:
        self.io.publish("tick", msg)


class TickRecorder(Node):
    """Records each Tick it handles, and whether the runner marked it busy meanwhile."""

    inputs = {"tick": Tick}

    def setup(self) -> None:
        self.seen: list[tuple[float, bool]] = []
        self.runner_busy = lambda: False  # the test points this at its runner

    def on_tick(self, msg: Tick) -> None:
        self.seen.append((msg.value, self.runner_busy()))


class TickDispatcher(TickRecorder):
    """Overrides ``handle`` (as the supervisors do): every message must pass through it."""

    def setup(self) -> None:
        super().setup()
        self.dispatched: list[str] = []

    def handle(self, port: str, msg: Message) -> None:
        self.dispatched.append(port)
        super().handle(port, msg)
