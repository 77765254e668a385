"""How the launcher starts its node processes: forks of a copy of itself.

Starting a fresh Python for each node cost every node its interpreter, numpy, ZeroMQ
and the codec (about 0.3 s of CPU each, a dozen times over on a few cores) and then its
node module's imports, which the launcher had just done to check the graph. Instead,
:class:`Starter` forks a *fork server* from the launcher once the graph is checked and
before the launcher opens any socket or starts any thread: a process holding every
module the check imported (the node modules with their OpenCV, CasADi, ...). For each
node the launcher sends it two pipe ends (the node's stdin and its output) over a Unix
socket; it forks twice and the intermediate exits, so the node is orphaned and the
kernel hands it to the launcher, which is a child subreaper (``PR_SET_CHILD_SUBREAPER``):
the launcher waits for its nodes, reads their exit codes and CPU time and signals their
process groups as it would its own children. A node is running in a few milliseconds,
sharing the server's memory until it writes to it. If the fork server dies, the next
start spawns a fresh one (``python -m runtime.child FD PID DIR``), which imports what every node
shares and lets each node import its own module; ``SBG_NODE_START=spawn`` starts with
such a server (for a library that cannot live through a fork, and for comparison).

A node process, in order:

1. leads its own process group (a Ctrl-C at the terminal reaches the launcher only,
   which stops the nodes in order), and takes SIGTERM and SIGINT as "end now" (a quiet
   exit) until ``runtime.runner`` takes them over as "stop cleanly";
2. waits to be handed to the launcher, then asks the kernel to send SIGTERM when the
   launcher dies (``PR_SET_PDEATHSIG``), and checks it has not died already;
3. reads its JSON spec on stdin (the launcher's pipe, which also carries the run's
   control secret: never a command line or the environment) and runs the node. A stdin
   closed with no spec ends it quietly.

A node runs numpy's BLAS on one thread unless ``OPENBLAS_NUM_THREADS`` says otherwise
(``launch.py`` sets it before numpy loads): a graph is a dozen processes on a few cores,
so a BLAS thread pool per process only oversubscribes them.

Each node ends the rest of its process group on its way out (the launcher also signals
the whole group, and kills what is left of it once the node is reaped), so a compiler the
node started goes with it. A node that outlives its launcher also removes the run
folder, so even a SIGKILLed launcher leaves no process and no ``sbg-*`` folder behind.
"""

from __future__ import annotations

import ctypes
import gc
import io
import json
import math
import os
import shutil
import signal
import socket
import struct
import sys
import time
from pathlib import Path
from typing import Any, BinaryIO

PR_SET_PDEATHSIG = 1
PR_SET_NAME = 15
PR_SET_CHILD_SUBREAPER = 36
SERVER_NAME = "sbg-fork-server"  # what ps and /proc/PID/comm call the fork server
# SBG_NODE_START=spawn: the fork server is a fresh Python from the start, so each node
# imports its own module (for a library that misbehaves after a fork; bench.startup).
START_ENV = "SBG_NODE_START"
PROJECT_ROOT = Path(__file__).resolve().parent.parent
GONE_WAIT_SECS = 0.2
DYING_WAIT_SECS = 30.0  # a launcher known to be dying (its socket closed without a word)
_END = b"end"  # what the launcher says before it closes the fork server's socket
SERVER_END_SECS = 0.5
HANDOVER_WAIT_SECS = 5.0
_PID = struct.Struct("=i")

_signalled = False


def _end_now(signum: int, frame: Any) -> None:
    global _signalled
    _signalled = True
    raise SystemExit(128 + signum)


def _prctl(option: int, value: int | bytes) -> bool:
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return bool(libc.prctl(option, value, 0, 0, 0) == 0)
    except (OSError, AttributeError):
        return False


def set_process_name(name: str) -> None:
    """What ``ps`` and ``top`` call this process (15 bytes at most; Linux)."""
    _prctl(PR_SET_NAME, name.encode()[:15])


def launcher_gone(parent: int) -> bool:
    """Whether the launcher has died (or is dying: a zombie whose threads still exit)."""
    if os.getppid() != parent:
        return True
    try:
        state = Path(f"/proc/{parent}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state in ("Z", "X")


def _wait_launcher_gone(parent: int) -> bool:
    """After a signal: the kernel sends PR_SET_PDEATHSIG when the *thread* that started
    this process dies, which can be a moment before the rest of the launcher is gone."""
    end = time.monotonic() + (GONE_WAIT_SECS if _signalled else 0.0)
    while not launcher_gone(parent):
        if time.monotonic() >= end:
            return False
        time.sleep(0.01)
    return True


def die_with_parent(parent_pid: int) -> None:
    """Let the kernel end this process when ``parent_pid`` dies (Linux); exit if it has."""
    _prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != parent_pid:
        sys.exit(0)


class NodeProcess:
    """A node process the launcher waits for (its child by adoption): what it needs of a
    ``subprocess.Popen``."""

    def __init__(self, pid: int, stdin: BinaryIO, stdout: BinaryIO) -> None:
        self.pid = pid
        self.stdin = stdin
        self.stdout = stdout
        self.returncode: int | None = None


class Starter:
    """The launcher's fork server (see the module's docstring). Make it after the graph
    check and before any socket or thread of the launcher; :meth:`close` at the end."""

    def __init__(self, rundir: Path) -> None:
        if not _prctl(PR_SET_CHILD_SUBREAPER, 1):
            raise OSError("PR_SET_CHILD_SUBREAPER failed: the launcher needs Linux")
        self.rundir = rundir
        self.launcher = os.getpid()
        self.server = 0
        if os.environ.get(START_ENV, "fork") == "spawn":
            self._spawn_server()
        else:
            self._fork_server()

    def _fork_server(self) -> None:
        self.sock, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the fork server
            self.sock.close()
            code = 0
            try:
                serve(theirs, self.launcher, str(self.rundir))
            except BaseException:  # noqa: BLE001 - never back into the launcher's code
                code = 1
            os._exit(code)
        theirs.close()
        self.server = pid

    def _spawn_server(self) -> None:
        self.sock, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            filter(None, [str(PROJECT_ROOT), env.get("PYTHONPATH")])
        )
        theirs.set_inheritable(True)
        args = [str(theirs.fileno()), str(self.launcher), str(self.rundir)]
        self.server = os.posix_spawn(
            sys.executable, [sys.executable, "-m", "runtime.child", *args], env, setpgroup=0
        )
        theirs.close()

    def start(self) -> NodeProcess:
        """A new node process, waiting for its spec on ``stdin``.

        Raises:
            OSError: neither the fork server nor a fresh one could start it.
        """
        try:
            return self._start()
        except OSError:
            self._respawn()  # the fork server died: a fresh one, once
            return self._start()

    def _start(self) -> NodeProcess:
        spec_r, spec_w = os.pipe()
        out_r, out_w = os.pipe()
        try:
            try:
                socket.send_fds(self.sock, [b"start"], [spec_r, out_w])
                reply = self.sock.recv(_PID.size)
            finally:
                os.close(spec_r)  # the node has them now
                os.close(out_w)
            if len(reply) != _PID.size:
                raise OSError("the fork server ended")
        except OSError:
            os.close(spec_w)
            os.close(out_r)
            raise
        (pid,) = _PID.unpack(reply)
        return NodeProcess(pid, os.fdopen(spec_w, "wb"), os.fdopen(out_r, "rb"))

    def _respawn(self) -> None:
        self._end_server()
        self._spawn_server()

    def _end_server(self) -> None:
        """Close its socket (it exits when it reads the end); kill it if it does not (a
        stopped server) within ``SERVER_END_SECS``."""
        try:
            self.sock.send(_END)  # a close without it says the launcher died
        except OSError:
            pass  # the server is gone already
        self.sock.close()
        end = time.monotonic() + SERVER_END_SECS
        while True:
            try:
                pid, _ = os.waitpid(self.server, os.WNOHANG)
            except ChildProcessError:
                return
            if pid:
                return
            if time.monotonic() > end:
                os.kill(self.server, signal.SIGKILL)
                end = math.inf
            time.sleep(0.005)

    def close(self) -> None:
        """End the fork server and stop adopting orphans."""
        self._end_server()
        _prctl(PR_SET_CHILD_SUBREAPER, 0)


def serve(sock: socket.socket, launcher: int, rundir: str) -> None:
    """The fork server's loop: a node process for each pair of pipe ends received.

    It ends when the launcher closes its socket, or dies (then it removes the run folder:
    the launcher may have died before it started any node)."""
    os.setpgid(0, 0)  # out of the terminal's process group: the launcher ends it
    set_process_name(SERVER_NAME)
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def launcher_died(signum: int, frame: Any) -> None:
        global _signalled
        _signalled = True
        if _wait_launcher_gone(launcher):
            shutil.rmtree(rundir, ignore_errors=True)
        os._exit(0)

    def launcher_dying() -> None:
        # Its end of the socket closed without _END: the launcher is dying. The kernel
        # closes a killed process's files before it signals its children (SIGTERM, above)
        # or hands them on, and on a busy machine that gap has no bound a fixed wait could
        # trust: wait for it to be gone, then remove the run folder.
        end = time.monotonic() + DYING_WAIT_SECS
        while not launcher_gone(launcher) and time.monotonic() < end:
            time.sleep(0.01)
        if launcher_gone(launcher):
            shutil.rmtree(rundir, ignore_errors=True)

    signal.signal(signal.SIGTERM, launcher_died)
    _prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    if os.getppid() != launcher:
        launcher_died(0, None)
    gc.freeze()  # what is imported stays shared with the nodes (no collector writes)
    while True:
        try:
            said, fds, _, _ = socket.recv_fds(sock, 16, 2)
        except OSError:
            said, fds = b"", []
        if len(fds) != 2:
            for fd in fds:
                os.close(fd)
            if said != _END:
                launcher_dying()
            return  # the launcher closed its end
        pid_r, pid_w = os.pipe()
        middle = os.fork()
        if middle == 0:
            os.close(pid_r)
            node = os.fork()
            if node == 0:
                os.close(pid_w)
                sock.close()
                _node(fds[0], fds[1], launcher, rundir)
            os.write(pid_w, _PID.pack(node))
            os._exit(0)
        os.close(pid_w)
        for fd in fds:
            os.close(fd)
        reply = os.read(pid_r, _PID.size)
        os.close(pid_r)
        os.waitpid(middle, 0)  # the node is the launcher's once its parent is gone
        sock.send(reply)


def _node(stdin: int, out: int, launcher: int, rundir: str) -> None:
    """A forked node process: never returns."""
    code: Any = 1
    try:
        os.setpgid(0, 0)
        signal.signal(signal.SIGTERM, _end_now)
        signal.signal(signal.SIGINT, _end_now)
        os.dup2(stdin, 0)
        os.dup2(out, 1)
        os.dup2(out, 2)
        os.close(stdin)
        os.close(out)
        sys.stdin = io.TextIOWrapper(io.FileIO(0, "r", closefd=False))
        sys.stdout = io.TextIOWrapper(io.FileIO(1, "w", closefd=False), write_through=True)
        sys.stderr = io.TextIOWrapper(io.FileIO(2, "w", closefd=False), write_through=True)
        adopted_by(launcher)
        code = run(launcher, rundir)
    except SystemExit as end:  # as Python ends: None is 0, a message goes to stderr and is 1
        code = 0 if end.code is None else end.code
        if not isinstance(code, int):
            print(code, file=sys.stderr)
    except BaseException:  # noqa: BLE001 - said on its output, never back into the server
        import traceback

        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code if isinstance(code, int) else 1)


def adopted_by(launcher: int) -> None:
    """Wait until the kernel has handed this process on (its parent, the fork server's
    intermediate, exits at once): to the launcher, or elsewhere if the launcher died."""
    middle = os.getppid()
    end = time.monotonic() + HANDOVER_WAIT_SECS
    while middle != launcher and os.getppid() == middle and time.monotonic() < end:
        time.sleep(0.001)


def run(launcher: int, rundir: str) -> int:
    """A node process's life after it started (see the module's docstring)."""
    try:
        die_with_parent(launcher)
        from runtime.runner import main as run_node

        text = sys.stdin.read()
        if not text:
            return 0  # no spec: the launcher stopped before it gave this one a node
        spec = json.loads(text)
        set_process_name(str(spec.get("name", "")))  # every node forked from one command line
        return run_node(spec)
    finally:
        # Leave nothing behind: what this node started (its own process group) ends with
        # it, and if the launcher is gone, so does the run folder.
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if os.getpgrp() == os.getpid():
            os.killpg(0, signal.SIGTERM)
        if rundir and _wait_launcher_gone(launcher):
            shutil.rmtree(rundir, ignore_errors=True)


def main() -> int:
    """``python -m runtime.child FD LAUNCHER_PID RUNDIR``: a fresh fork server, for when
    the first one died (it imports what every node shares; each node imports its own)."""
    fd, launcher, rundir = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    import runtime.runner  # noqa: F401 - shared by every node, imported once here

    serve(socket.socket(fileno=fd), launcher, rundir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
