"""Every message published is in one column of the end-of-run table, to the message."""

from __future__ import annotations

import json
from pathlib import Path

from tests.faults.test_supervision import launcher_for
from tests.runtime.conftest import table_row
from tests.synthetic_nodes import IMPLS

LOSSES = ("delivered", "dropped", "unreceived", "superseded", "bad")


def test_a_flood_into_slow_subscribers_is_accounted_for_to_the_message(tmp_path: Path) -> None:
    slow = {"impl": IMPLS["synthetic.sink"]}
    queue_out, latest_out = tmp_path / "queue.jsonl", tmp_path / "latest.jsonl"
    launcher, out = launcher_for(
        {
            "src": {
                "impl": IMPLS["synthetic.source"],
                "params": {"rate_hz": 20000, "count": 10**9, "stop_when_done": False},
            },
            "queue": {
                **slow,
                "params": {"work_secs": 0.005, "out_path": str(queue_out)},
                "inputs": {"tick": {"from": "src/tick", "queue_size": 100}},
            },
            "latest": {
                **slow,
                "params": {"work_secs": 0.005, "out_path": str(latest_out)},
                "inputs": {"tick": {"from": "src/tick", "policy": "latest"}},
            },
        },
        duration_secs=3.0,
    )
    code = launcher.run()
    log = out.getvalue()
    assert code == 0, log
    for node, handled in (("queue", queue_out), ("latest", latest_out)):
        row = table_row(log, f"src/tick -> {node}.tick")
        assert row["messages"] == sum(row[column] for column in LOSSES), (node, row, log)
        # delivered: exactly what the node was handed
        assert row["delivered"] == len(handled.read_text().splitlines()), (node, row, log)
        assert row["messages"] > 2 * row["delivered"], (node, row, log)  # it was a flood
    queue = table_row(log, "src/tick -> queue.tick")
    assert queue["dropped"] + queue["unreceived"] > 0 and queue["superseded"] == 0, log
    latest = table_row(log, "src/tick -> latest.tick")
    assert latest["superseded"] > 0, log
    seqs = [json.loads(line)["seq"] for line in queue_out.read_text().splitlines()]
    gaps = sum(b - a - 1 for a, b in zip(seqs, seqs[1:], strict=False))
    assert queue["dropped"] == gaps, log  # the gaps between messages it handled
