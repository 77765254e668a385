"""Recording and lockstep replay across two hosts, both on this machine's loopback (two
port ranges of 127.0.0.1, no keys): two launcher processes, ``--host a`` and ``--host b``.

The graph puts the fan-in (``merge``) on ``b`` and its consumer on ``a``, so a replay
of it crosses the hosts both ways, and its idle barrier needs both hosts' counts.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from runtime.bag import BagReader
from runtime.bag.diff import diff_bags
from tests.hosts.conftest import SYNTHETIC, Launched, free_port_range, write_graph
from tests.runtime.conftest import topic_messages

NODES = {
    "source_b": {
        "impl": f"{SYNTHETIC}Source",
        "host": "a",
        "params": {"rate_hz": 80, "count": 16, "stop_when_done": False},
    },
    "sink": {"impl": f"{SYNTHETIC}Sink", "host": "a", "inputs": {"tick": "merge/tick"}},
    "source_a": {
        "impl": f"{SYNTHETIC}Source",
        "host": "b",
        "params": {"rate_hz": 200, "count": 40},
    },
    "relay": {
        "impl": f"{SYNTHETIC}Relay",
        "host": "b",
        "params": {"add": 1000},
        "inputs": {"tick": "source_a/tick"},
    },
    "merge": {
        "impl": f"{SYNTHETIC}Merge",
        "host": "b",
        "inputs": {"a": "relay/tick", "b": "source_b/tick"},
    },
}


@pytest.fixture(scope="module")
def graph() -> dict:
    """The graph on two port ranges of 127.0.0.1 that no other run of the suite uses."""
    hosts = {h: {"address": "127.0.0.1", "ports": list(free_port_range(20))} for h in "ab"}
    return {"hosts": hosts, "nodes": NODES}


def run_on_hosts(
    args: list[str | Path], log: Path, hosts: tuple[str, ...] = ("a", "b")
) -> list[Launched]:
    """``launch.py ARGS --host H`` for each host at once (no hosts: ``launch.py ARGS``);
    each one's exit code must be 0."""
    runs = [([*args, "--host", h], f".{h}.log") for h in hosts] or [(args, ".log")]
    started = [Launched(argv, log.with_suffix(suffix)) for argv, suffix in runs]
    try:
        for item in started:
            assert item.finish() == 0, item.text[-3000:]
    finally:
        for item in started:
            item.kill()
    return started


def values(path: Path, topic: str) -> list[float]:
    with BagReader(path) as r:
        return [m.decode_plain()["value"] for m in r.messages([topic])]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory, graph: dict) -> tuple[Path, list[Launched]]:
    """The graph run on two hosts with --record: the bag (written on a) and the launchers."""
    tmp = tmp_path_factory.mktemp("hosts")
    path = write_graph(graph, tmp / "g.yaml")
    bag = tmp / "live.mcap"
    return bag, run_on_hosts([path, "--record", bag, "--log-level", "WARNING"], tmp / "live")


def test_record_across_hosts_records_every_message_published_on_the_other(
    recorded: tuple[Path, list[Launched]], graph: dict
) -> None:
    bag, (a, b) = recorded
    assert "[recorder]" not in b.text  # the recorder runs on the first host only
    with BagReader(bag) as r:
        counts = {t: s.messages for t, s in r.stats().items()}
        stored = yaml.safe_load(r.run_info()["graph_yaml"])
        command = r.run_info()["command_line"]
    # source_a and relay publish on b; the bag is written on a: every message, as b counted.
    for topic in ("source_a/tick", "relay/tick", "merge/tick"):
        assert counts[topic] == topic_messages(b.text, topic), topic
    assert counts == {"source_a/tick": 40, "relay/tick": 40, "source_b/tick": 16, "merge/tick": 56}
    assert stored["hosts"] == graph["hosts"]  # the bag replays across the same hosts
    assert "--host" not in command and command.startswith("python launch.py")


def test_lockstep_replay_split_over_two_hosts_gives_the_one_host_output(
    recorded: tuple[Path, list[Launched]], tmp_path: Path
) -> None:
    bag, _ = recorded
    replay = ["replay", bag, "--swap", "relay", "--lockstep", "--log-level", "WARNING"]
    one = tmp_path / "one.mcap"
    (alone,) = run_on_hosts([*replay, "--record", one, "--no-hosts"], tmp_path / "one", ())
    # In lockstep the merge (on b) sees its inputs in the bag's order of the sources.
    with BagReader(bag) as r:
        order = [
            (1000.0 if m.topic == "source_a/tick" else 0.0) + m.decode_plain()["value"]
            for m in r.messages(["source_a/tick", "source_b/tick"])
        ]
    assert values(one, "merge/tick") == order and len(order) == 56
    for run in ("two1", "two2"):
        out = tmp_path / f"{run}.mcap"
        a, b = run_on_hosts([*replay, "--record", out], tmp_path / run)
        assert diff_bags(one, out) == [], run
        assert "host 'a' stops: replay" in b.text  # the replay (on a) ended the run


def test_a_host_started_without_lockstep_is_refused_naming_the_flag(
    tmp_path: Path, graph: dict
) -> None:
    path, bag = write_graph(graph, tmp_path / "g.yaml"), tmp_path / "o.mcap"
    a = Launched([path, "--host", "a", "--lockstep", "--record", bag], tmp_path / "a.log")
    b = Launched([path, "--host", "b"], tmp_path / "b.log")
    try:
        assert a.finish() == 2 and b.finish() == 2
    finally:
        a.kill()
        b.kill()
    assert "host 'b' runs another graph or run mode" in a.text
    assert "host 'b' was started with nothing that this host was not" in a.text
    assert f"and this host with --lockstep --record {bag} that it was not" in a.text
    assert f"host 'a' was started with --lockstep --record {bag} that this host" in b.text


def test_a_replay_across_hosts_without_host_says_what_to_run_on_each(
    recorded: tuple[Path, list[Launched]], tmp_path: Path
) -> None:
    bag, _ = recorded
    run = Launched(["replay", bag, "--swap", "relay"], tmp_path / "r.log")
    assert run.finish() == 2
    assert "places its nodes on 2 hosts" in run.text
    assert f"launch.py replay {bag} --swap relay --host a" in run.text
    assert "on a (127.0.0.1, nodes sink, replay):" in run.text  # the replay on the first host
    both = Launched(["replay", bag, "--no-hosts", "--host", "a"], tmp_path / "b.log")
    assert both.finish() == 2 and "--no-hosts and --host: give one of them" in both.text
