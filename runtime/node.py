"""The Node base class: declared ports, typed parameters, handlers, timers.

A node's logic never builds its own transport: it receives an :class:`IO` object.
In a graph that is the ZeroMQ process runner (``runtime.runner``); in tests it is
:class:`runtime.testing.FakeIO`, which feeds messages and records outputs.

A node class declares::

    @register("shear_tracker.farneback")
    class FarnebackShearTracker(Node):
        Params = ShearParams                 # a declared msgspec Struct (runtime.params)
        inputs = {"image": ToFImage, "grasp": GraspState}
        outputs = {"shear": ShearEstimate}
        optional_inputs = frozenset({"grasp"})   # others are required in a graph

        def setup(self) -> None: ...          # after construction, before messages
        def on_image(self, msg: ToFImage) -> None: ...   # one handler per input
        def teardown(self) -> None: ...       # on a clean stop

Sources (nodes without inputs) drive themselves with ``self.io.add_timer`` and end
the graph with ``self.io.request_stop(reason)`` when they are done.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Protocol

import msgspec

from messages.base import Message
from messages.errors import NodeError


class NoParams(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Parameters of a node that takes none."""


class IO(Protocol):
    """What a node may do to the outside world."""

    log: logging.Logger
    stop_requested: bool  # True once the graph is stopping this node

    def publish(self, output: str, msg: Message) -> None:
        """Send ``msg`` on one of the node's declared outputs (the IO sets ``header.seq``)."""

    def add_timer(self, period_secs: float, callback: Callable[[], None]) -> None:
        """Call ``callback`` every ``period_secs`` (on the node's own thread).

        In lockstep, unless the node is ``clocked`` or has no inputs, ``callback`` runs
        once after each message the node handles instead: bag-driven, not clock-driven."""

    def cancel_timer(self, callback: Callable[[], None]) -> None:
        """Stop the timers added with ``callback`` (none: nothing happens). A node whose
        timed phase is over cancels its timer rather than being woken for nothing; a timer
        cancelled by another's callback does not run again, even in the same round."""

    def now_nanos(self) -> int:
        """The current time in nanoseconds (wall clock in a live graph)."""

    def request_stop(self, reason: str, *, exit_code: int = 0) -> None:
        """Ask the whole graph to stop (a source that has finished, a task that ended).

        A non-zero ``exit_code`` is the node's verdict on the run (a task that put an
        object in the wrong bin): the launcher exits with it once the graph has stopped
        cleanly (messages in flight still reach the recorder)."""

    def publish_raw(self, topic: str, frames: list[Any], decoded: Message | None = None) -> None:
        """Publish already-encoded frames verbatim on one of the node's output topics.

        ``decoded``: the message the frames carry, if the caller has it (the replay
        decodes each one): its finite fields are then checked as :meth:`publish` checks."""

    def wait_idle(self, timeout_secs: float, *, last: bool = False) -> bool:
        """Block until every message published so far has been handled downstream
        (lockstep replay); True when idle, False on timeout. ``last``: the caller has
        published its last message, so the messages a node holds in stamp order
        (``ordered_inputs``) are handled too."""

    def lockstep_barrier(self, topic: str) -> bool:
        """Whether, in lockstep, a message on ``topic`` must wait for the graph to be idle:
        it can reach a node that merges several publishers (``Graph.barrier_topics``)."""

    def drops(self) -> dict[str, int]:
        """Messages lost per input topic so far (sequence gaps and superseded ones)."""


class Node:
    """Base of every node implementation. See the module docstring for the shape."""

    Params: ClassVar[type[Any]] = NoParams
    inputs: ClassVar[dict[str, type[Message]]] = {}
    outputs: ClassVar[dict[str, type[Message]]] = {}
    optional_inputs: ClassVar[frozenset[str]] = frozenset()
    # A raw-input node (the recorder) receives every message undecoded through
    # ``on_raw(topic, frames)``, and its graph inputs may name any port and type.
    raw_input: ClassVar[bool] = False
    # True when nothing the node publishes or writes depends on how the messages of
    # different publishers interleave (the recorder keeps each topic in its own order):
    # lockstep replay then need not wait for the graph to be idle for its sake.
    merges_in_any_order: ClassVar[bool] = False
    # True for a node whose work follows the clock or a device rather than its inputs: a
    # simulated world (one step per frame period), a device driver. In lockstep its timers
    # keep the clock; every other node's timers run once after each message it handles
    # there instead (``runtime.runner``), so what they publish depends on the bag alone.
    # A node without inputs (a source, the replay, the recorder) keeps the clock anyway.
    clocked: ClassVar[bool] = False
    # Inputs whose messages the node must see in stamp order across each other (a
    # decision taken from several inputs whose paths differ in length): the runtime holds
    # each until the others have advanced past its stamp, live at most
    # ``order_window_secs``, without a bound in lockstep (``runtime.ordering``).
    ordered_inputs: ClassVar[tuple[str, ...]] = ()
    order_window_secs: ClassVar[float] = 0.5
    # Live, per ordered input, the ordered inputs its messages wait for, when not every
    # other: a decision that reads only some of them is not held back by the others'
    # longer paths. Lockstep ignores it (every input waits for every other).
    order_waits: ClassVar[Mapping[str, tuple[str, ...]]] = {}

    def __init__(self, name: str, params: Any, io: IO) -> None:
        if not isinstance(params, self.Params):
            raise NodeError(
                f"{name}: params must be {self.Params.__name__}, got {type(params).__name__}"
            )
        self.name = name
        self.params = params
        self.io = io

    def setup(self) -> None:
        """Build the node's state; called once before the first message or timer."""

    def teardown(self) -> None:
        """Release resources; called once on a clean stop, only if :meth:`setup` ran."""

    @classmethod
    def ports(cls, params: Any) -> tuple[dict[str, type[Message]], dict[str, type[Message]]]:
        """``(inputs, outputs)`` for these parameters; the class attributes by default.

        Override when the ports depend on the parameters (a replay node's outputs are
        the topics of its bag). An output name containing '/' is a full topic.
        """
        return cls.inputs, cls.outputs

    def on_raw(self, topic: str, frames: list[Any]) -> None:
        """Receive an undecoded multipart message (only for ``raw_input`` nodes)."""
        raise NotImplementedError(f"{type(self).__name__} is not a raw-input node")

    def handle(self, port: str, msg: Message) -> None:
        """Dispatch a received message to ``on_<port>``."""
        getattr(self, f"on_{port}")(msg)

    @classmethod
    def check_declaration(cls) -> None:
        """Raise ``TypeError`` if a declared input has no handler (called at registration)."""
        for port in cls.inputs:
            if not callable(getattr(cls, f"on_{port}", None)):
                raise TypeError(f"{cls.__name__}: input {port!r} has no on_{port} handler")
        for what, ports in (("optional", cls.optional_inputs), ("ordered", cls.ordered_inputs)):
            unknown = set(ports) - set(cls.inputs)
            if unknown:
                raise TypeError(
                    f"{cls.__name__}: {what}_inputs names unknown ports {sorted(unknown)}"
                )
        waits = {p for port, of in cls.order_waits.items() for p in (port, *of)}
        if waits - set(cls.ordered_inputs):
            raise TypeError(
                f"{cls.__name__}: order_waits names ports that are not ordered inputs"
                f" {sorted(waits - set(cls.ordered_inputs))}"
            )
