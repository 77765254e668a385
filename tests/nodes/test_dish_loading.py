"""supervisor.dish_loading as a state machine, driven through FakeIO (no classifier)."""

from __future__ import annotations

import itertools

import msgspec
import numpy as np
import pytest

from messages import ClassProbabilities, GraspState, GroundTruth, Header
from nodes.supervisor.dish_loading import DishLoadingSupervisor
from perception.classify.autolabel import GraspGenerator
from runtime.params import build_params
from runtime.testing import feed, make_node

CLASSES = ["mug", "pet_bottle", "square_bottle", "wine_glass"]


class Sink:
    """Plays world, grasp monitor and classifier for the supervisor, 30 frames a second."""

    def __init__(self, params: dict, answer) -> None:  # noqa: ANN001
        self.node, self.io = make_node(DishLoadingSupervisor, params)
        self.answer = answer  # (true class, attempt) -> probabilities
        self.t = 0.0
        self.stable = False
        self.places = 0

    def stamp(self) -> Header:
        return Header(stamp_nanos=int(1e18 + self.t * 1e9))

    def frame(self) -> None:
        self.t += 1 / 30
        commands = self.io.published["command"]
        closed = bool(commands) and commands[-1].command == "grasp"
        place = self.io.published["place"][-1]
        # Stable 0.4 s after the grasp command, released as soon as the jaws open.
        closed_for = self.t - getattr(self, "closed_at", self.t) if closed else 0.0
        if closed and not hasattr(self, "closed_at"):
            self.closed_at = self.t
        if not closed and hasattr(self, "closed_at"):
            del self.closed_at
        event = ""
        if closed and closed_for >= 0.4 and not self.stable:
            self.stable, event = True, "stable"
        elif not closed and self.stable:
            self.stable, event = False, "released"
        feed(self.node, "grasp", GraspState(header=self.stamp(), stable=self.stable, event=event))
        truth = GroundTruth(
            header=self.stamp(),
            tool_from_object=np.eye(4),
            object_class=place.class_label,
            in_contact=self.stable,
            shear_left_m=np.zeros(2),
            shear_right_m=np.zeros(2),
            noise_seed=0,
        )
        feed(self.node, "truth", truth)
        if self.stable:
            attempt = len(self.io.published["place"])
            probs = np.float32(self.answer(place.class_label, attempt))
            feed(
                self.node,
                "classes",
                ClassProbabilities(header=self.stamp(), classes=CLASSES, probabilities=probs),
            )

    def run(self, max_secs: float = 120.0) -> None:
        self.io.advance(0.5)  # the wall-clock start: the first object is placed
        while self.io.stop_reason is None and self.t < max_secs:
            self.frame()

    def events(self, name: str) -> list[dict]:
        """The records of the task's ``name`` events, as plain values."""
        return [msgspec.to_builtins(e.data) for e in self.io.published["event"] if e.event == name]


def one_hot(name: str, p: float = 0.97) -> list[float]:
    rest = (1 - p) / 3
    return [p if c == name else rest for c in CLASSES]


def test_every_object_goes_to_its_bin_and_the_summary_says_so() -> None:
    sink = Sink({"objects": 6, "seed": 2}, lambda true, attempt: one_hot(true))
    sink.run()
    objects = sink.events("object")
    assert len(objects) == 6 and {o["true_class"] for o in objects} == set(CLASSES)
    bins = {"mug": "dishwasher", "wine_glass": "dishwasher"}
    for o in objects:
        assert o["destination"] == bins.get(o["true_class"], "recycling") and o["right"]
    assert sink.events("summary")[0]["wrong"] == 0
    assert sink.io.stop_exit_code == 0 and "6 right, 0 wrong" in sink.io.stop_reason


def test_a_wrong_bin_makes_the_verdict_fail() -> None:
    def answer(true: str, attempt: int) -> list[float]:
        return one_hot("mug" if true == "pet_bottle" else true)

    sink = Sink({"objects": 4, "seed": 0}, answer)
    sink.run()
    wrong = [o for o in sink.events("object") if o["right"] is False]
    assert [o["true_class"] for o in wrong] == ["pet_bottle"]
    assert wrong[0]["destination"] == "dishwasher"
    assert sink.io.stop_exit_code == 1


def test_an_unsure_object_is_regrasped_at_another_height_then_goes_to_manual() -> None:
    def answer(true: str, attempt: int) -> list[float]:
        return one_hot(true, 0.5) if true == "wine_glass" else one_hot(true)

    sink = Sink({"objects": 4, "seed": 0, "max_regrasps": 2}, answer)
    sink.run()
    glass = next(o for o in sink.events("object") if o["true_class"] == "wine_glass")
    assert glass["regrasps"] == 2 and glass["destination"] == "manual" and glass["right"] is None
    places = [p for p in sink.io.published["place"] if p.object_name == "wine_glass"]
    assert len(places) == 3
    # Each regrasp's grasp point lies at least min_height_change_m (15 mm) from the last.
    node = sink.node
    first = node.generator.sample(places[0].grasp_id)
    regrasps = GraspGenerator(node.params.generator_params(("wine_glass",)))
    heights = [first.height_m] + [regrasps.sample(p.grasp_id).height_m for p in places[1:]]
    assert all(abs(a - b) >= 0.015 for a, b in itertools.pairwise(heights)), heights
    assert sink.io.stop_exit_code == 0  # the manual bin is not a wrong bin


def test_a_regrasp_that_becomes_sure_is_routed() -> None:
    sink = Sink({"objects": 1}, lambda true, attempt: one_hot(true, 0.6 if attempt == 1 else 0.97))
    sink.run()
    (only,) = sink.events("object")
    assert only["regrasps"] == 1 and only["right"] is True


def test_params_check_themselves() -> None:
    with pytest.raises(ValueError, match="objects"):
        build_params(DishLoadingSupervisor.Params, {"objects": 0})
    with pytest.raises(ValueError, match="bins"):
        build_params(DishLoadingSupervisor.Params, {"bins": [["mug", "dishwasher"]]})
    with pytest.raises(ValueError, match="max_regrasps"):
        build_params(DishLoadingSupervisor.Params, {"max_regrasps": -1})
