"""A node's verdict (``request_stop(reason, exit_code=N)``) is the launcher's exit code."""

from __future__ import annotations

from pathlib import Path

import msgspec

from messages import Header, Tick
from runtime.node import Node
from tests.runtime.conftest import GraphRun, sink


class VerdictParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    count: int = 20
    exit_code: int = 0


class VerdictSource(Node):
    """Publishes ``count`` ticks, then stops the graph with its verdict."""

    Params = VerdictParams
    outputs = {"tick": Tick}

    def setup(self) -> None:
        self.sent = 0
        self.io.add_timer(0.01, self._tick)

    def _tick(self) -> None:
        if self.sent < self.params.count:
            self.io.publish("tick", Tick(header=Header(), value=float(self.sent)))
            self.sent += 1
        elif self.sent == self.params.count:
            self.sent += 1
            self.io.request_stop("verdict given", exit_code=self.params.exit_code)


def test_a_failing_verdict_is_the_exit_code_and_nothing_in_flight_is_lost(
    graph_run: GraphRun, tmp_path: Path
) -> None:
    for code in (0, 3):
        out = tmp_path / f"sink{code}.jsonl"
        graph = graph_run.write(
            {
                "src": {
                    "impl": "tests.runtime.test_verdict:VerdictSource",
                    "params": {"exit_code": code},
                },
                "sink": sink(out, "src/tick"),
            }
        )
        got, log = graph_run.run(graph)
        assert got == code, log
        assert len(graph_run.rows(out)) == 20  # the drain was not cut short
        assert ("reports failure (exit code 3)" in log) == (code == 3)
