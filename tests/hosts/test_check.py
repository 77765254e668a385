"""A graph on several hosts, as checked and started: what is refused, and why (no root
needed: nothing here binds a namespace's address)."""

from __future__ import annotations

import functools
import os
import socket
from pathlib import Path

import pytest

from cli.options import shared_command_line
from cli.run import host_keys
from messages.errors import GraphError
from runtime.graph import check
from runtime.hosts import without_hosts
from runtime.security import _peer_of, load_key, make_key
from tests.hosts.conftest import two_host_graph, write_graph
from tests.launching import launch_py

launch = functools.partial(launch_py, timeout=120)


def errors_of(doc: dict) -> str:
    with pytest.raises(GraphError) as err:
        check(doc, source="g.yaml")
    return str(err.value)


def test_a_node_binding_an_address_off_loopback_without_keys_is_refused_with_why() -> None:
    err = errors_of({"nodes": {"a": {"impl": "synthetic.source", "host": "0.0.0.0"}}})
    assert "g.yaml: node 'a'.host: must be a loopback address (127.0.0.1), got '0.0.0.0'" in err
    assert "unencrypted and unauthenticated" in err
    assert "hosts:" in err and "public key" in err


def test_a_host_off_loopback_without_a_public_key_is_refused(tmp_path: Path) -> None:
    doc = two_host_graph(tmp_path)
    del doc["hosts"]["b"]["public_key"]
    err = errors_of(doc)
    assert "g.yaml: hosts.b.public_key: required: 10.77.0.2 is not a loopback address" in err
    assert "launch.py keys make b" in err


def test_bad_hosts_tables_and_placements_name_the_field(tmp_path: Path) -> None:
    doc = two_host_graph(tmp_path)
    doc["hosts"]["a"]["ports"] = [24000, 24001]  # the link and one node only
    doc["hosts"]["b"]["address"] = "workstation.local"
    doc["hosts"]["c"] = {"address": "10.77.0.1", "ports": [24001, 24002], "public_key": "x"}
    doc["on_host_lost"] = "panic"
    doc["host_timeout_secs"] = 0
    doc["nodes"]["extra"] = {"impl": "synthetic.source", "host": "a", "params": {"count": 1}}
    doc["nodes"]["lost"] = {"impl": "synthetic.source", "host": "nowhere"}
    err = errors_of(doc)
    assert "g.yaml: hosts.b.address: must be an IP address, got 'workstation.local'" in err
    assert "g.yaml: hosts.c.public_key: must be a Z85 CURVE public key" in err
    assert "g.yaml: hosts.c.ports: overlaps a's on the same address" in err
    assert "g.yaml: on_host_lost: must be one of ('wait', 'stop'), got 'panic'" in err
    assert "g.yaml: host_timeout_secs: must be a finite number > 0, got 0" in err
    assert "g.yaml: node 'lost'.host: 'nowhere' is not a host of the hosts table" in err
    assert "g.yaml: hosts.a.ports: 2 node(s) and the link need 3 ports" in err
    assert "g.yaml: on_host_lost: only with a 'hosts' table" in errors_of(
        {"on_host_lost": "wait", "nodes": {"a": {"impl": "synthetic.source"}}}
    )


def test_endpoints_follow_the_table_so_every_host_knows_them(tmp_path: Path) -> None:
    graph = check(two_host_graph(tmp_path))
    placed = graph.hosts.placement({n: s.host for n, s in graph.nodes.items()})
    assert placed == {"src": "a", "sink": "b"}
    assert graph.hosts.endpoints(placed) == {
        "src": "tcp://10.77.0.1:24001",
        "sink": "tcp://10.77.0.2:24001",
    }
    assert graph.hosts.table["a"].link == "tcp://10.77.0.1:24000"


def test_keys_make_and_list_keep_the_secret_key_private(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    made = launch("keys", "make", "robot", "--keys", keys)
    assert made.returncode == 0, made.stderr
    public = (keys / "robot.pub").read_text().strip()
    assert f'public_key: "{public}"' in made.stdout
    assert (keys / "robot.key").stat().st_mode & 0o777 == 0o600
    assert keys.stat().st_mode & 0o777 == 0o700
    assert load_key(keys / "robot.key").public == public
    again = launch("keys", "make", "robot", "--keys", keys)
    assert again.returncode == 2 and "exists" in again.stderr
    listed = launch("keys", "list", "--keys", keys)
    assert f"robot            {public}  secret key here" in listed.stdout


def test_a_key_file_others_can_read_or_not_the_graphs_key_is_refused(tmp_path: Path) -> None:
    graph = check(two_host_graph(tmp_path))
    assert host_keys(graph, "a", tmp_path) is not None
    os.chmod(tmp_path / "a.key", 0o644)
    with pytest.raises(GraphError, match=r"a.key: the secret key is readable by others"):
        host_keys(graph, "a", tmp_path)
    make_key(tmp_path, "a", overwrite=True)  # a new pair: not the key the graph names
    with pytest.raises(GraphError, match=r"hosts.a.public_key is not the public key of"):
        host_keys(graph, "a", tmp_path)
    with pytest.raises(GraphError, match=r"host 'b' needs its secret key at .*nokeys/b.key"):
        host_keys(graph, "b", tmp_path / "nokeys")
    with pytest.raises(GraphError, match=r"--host 'c' is not a host of the graph's hosts table"):
        host_keys(graph, "c", tmp_path)


def test_a_hosts_key_file_is_read_from_where_the_table_says(tmp_path: Path) -> None:
    doc = two_host_graph(tmp_path)
    elsewhere = tmp_path / "etc"
    doc["hosts"]["b"]["public_key"] = make_key(elsewhere, "workstation").public
    doc["hosts"]["b"]["key_file"] = str(elsewhere / "workstation.key")
    keys = host_keys(check(doc), "b", tmp_path / "nokeys")  # not KEYDIR/b.key
    assert keys is not None and keys.public == doc["hosts"]["b"]["public_key"]


def test_without_host_it_says_what_to_run_on_each_host(tmp_path: Path) -> None:
    graph = write_graph(two_host_graph(tmp_path), tmp_path / "g.yaml")
    elsewhere = launch(graph, "--check", "--host", "a", "--keys", tmp_path)
    assert elsewhere.returncode == 2  # 10.77.0.1 is not this machine's (see test_netns)
    assert "--host a: cannot listen on tcp://10.77.0.1:24000 here" in elsewhere.stderr
    assert "is this machine a (10.77.0.1)" in elsewhere.stderr
    run = launch(graph, "--keys", tmp_path)
    assert run.returncode == 2
    assert "places its nodes on 2 hosts" in run.stderr
    assert f"launch.py {graph} --keys {tmp_path} --host a" in run.stderr
    assert "on b (10.77.0.2, nodes sink):" in run.stderr


def test_without_hosts_drops_the_table_its_policies_and_placements(tmp_path: Path) -> None:
    doc = two_host_graph(tmp_path)
    alone = without_hosts(doc)
    assert set(alone) == {"nodes"} and "hosts" in doc  # a copy
    assert all("host" not in body for body in alone["nodes"].values())
    assert not check(alone).hosts.table
    loopback = {"nodes": {"a": {"impl": "synthetic.source", "host": "127.0.0.1"}}}
    assert without_hosts(loopback) == loopback  # no table: a node's address stays


def test_the_shared_command_line_is_the_same_on_every_host() -> None:
    a = shared_command_line(["launch.py", "g.yaml", "--record", "o.mcap", "--host", "a"])
    b = shared_command_line(["launch.py", "g.yaml", "--keys=/k", "--record", "o.mcap"])
    assert a == b == "python launch.py g.yaml --record o.mcap"
    assert shared_command_line(["launch.py", "g.yaml"]).endswith(" launch.py g.yaml")


def test_the_peer_of_a_connection_number_reused_by_a_local_socket_is_unknown() -> None:
    # The monitor names an accepted connection by its file descriptor; by the time the
    # guard reads it the connection can be gone and its number taken by a Unix socket
    # (a getpeername of '' that once ended the guard's thread, and every later handshake
    # of that launcher with it), or by no socket at all.
    a, b = socket.socketpair()
    with a, b:
        assert _peer_of(a.fileno()) == "an unknown address"
    with open(os.devnull) as f:
        assert _peer_of(f.fileno()) == "an unknown address"
    with socket.create_server(("127.0.0.1", 0)) as server:
        with socket.create_connection(server.getsockname()) as c:
            assert _peer_of(c.fileno()) == f"127.0.0.1:{server.getsockname()[1]}"
