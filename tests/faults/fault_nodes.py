"""Node classes for the fault-injection tests (named as ``module:Class`` in graphs)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import msgspec

from messages import Header, Pressure, Tick, encode
from runtime.node import IO, Node


class TickerParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    rate_hz: float = 50.0
    init_secs: float = 0.0  # sleep while being built: a node still importing its module
    crash_after: int = 0  # ticks, then exit 3 once (a marker file remembers it)
    crash_marker: str = ""
    restarted_init_secs: float = 0.0  # the restarted incarnation's start-up time
    exit_message: str = ""  # sys.exit(this) in setup: a node that ends itself as Python does
    disk_full_at_stop: bool = False  # teardown fails as a recorder's does when the disk is full


class Ticker(Node):
    """Publishes ticks forever; slow to build and crashing once on request."""

    Params = TickerParams
    outputs = {"tick": Tick}

    def __init__(self, name: str, params: Any, io: IO) -> None:
        super().__init__(name, params, io)
        marker = Path(params.crash_marker) if params.crash_marker else None
        restarted = marker is not None and marker.exists()
        time.sleep(params.restarted_init_secs if restarted else params.init_secs)
        self.crash = params.crash_after and not restarted

    def setup(self) -> None:
        if self.params.exit_message:
            sys.exit(self.params.exit_message)
        self.sent = 0
        self.io.add_timer(1.0 / self.params.rate_hz, self.tick)

    def teardown(self) -> None:
        if self.params.disk_full_at_stop:
            raise OSError(28, "No space left on device")

    def tick(self) -> None:
        self.io.publish("tick", Tick(header=Header(stamp_nanos=self.io.now_nanos())))
        self.sent += 1
        if self.crash and self.sent >= self.params.crash_after:
            Path(self.params.crash_marker).touch()
            os._exit(3)


class CorruptParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    count: int = 120
    corrupt_every: int = 30  # every n-th tick carries a wild seq
    garbage_every: int = 20  # every n-th publication is followed by an undecodable frame


class SeqCorrupter(Node):
    """Ticks 0..count-1 whose seq is sometimes wild, interleaved with undecodable frames."""

    Params = CorruptParams
    outputs = {"tick": Tick}

    def setup(self) -> None:
        self.sent = 0
        self.io.add_timer(0.005, self.tick)

    def tick(self) -> None:
        if self.sent >= self.params.count:
            return
        topic = f"{self.name}/tick"
        seq = self.sent
        if self.sent % self.params.corrupt_every == self.params.corrupt_every - 1:
            seq = 10**9 + self.sent if self.sent % 2 else 0
        frames = encode(topic, Tick(header=Header(seq=seq), value=float(self.sent)))
        self.io.publish_raw(topic, frames)
        if self.sent % self.params.garbage_every == 0:
            self.io.publish_raw(topic, [topic.encode(), b"\xc1 not a header"])
        self.sent += 1
        if self.sent == self.params.count:
            self.io.request_stop("corrupting done")


class BadPressureParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    count: int = 40


class BadPressure(Node):
    """Pressures of which every other is NaN or infinite (a broken sensor or bag)."""

    Params = BadPressureParams
    outputs = {"pressure": Pressure}

    def setup(self) -> None:
        self.sent = 0
        self.io.add_timer(0.01, self.tick)

    def tick(self) -> None:
        if self.sent >= self.params.count:
            return
        value = (math.nan, 1200.0, math.inf, 1300.0)[self.sent % 4]
        msg = Pressure(header=Header(), sensor="left", pressure_pa=value)
        self.io.publish("pressure", msg)
        self.sent += 1
        if self.sent == self.params.count:
            self.io.request_stop("pressures done")


class PressureSink(Node):
    """Takes pressures and does nothing with them."""

    inputs = {"pressure": Pressure}

    def on_pressure(self, msg: Pressure) -> None:
        pass


class SpawnerParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pid_file: str


class Spawner(Node):
    """Starts a long-running helper process (as a node building a solver starts gcc)."""

    Params = SpawnerParams
    outputs = {"tick": Tick}

    def setup(self) -> None:
        self.helper = subprocess.Popen(["sleep", "120"])
        Path(self.params.pid_file).write_text(str(self.helper.pid))
