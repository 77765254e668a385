"""Registers the test-only nodes (``synthetic.*``) in every test process; shared fixtures."""

from __future__ import annotations

import pytest

import tests.synthetic_nodes  # noqa: F401  (registers synthetic.source, .relay, .merge, .sink)
from messages.base import Message


@pytest.fixture
def scratch_registry(monkeypatch: pytest.MonkeyPatch) -> dict[str, type[Message]]:
    """A copy of the message registry for the test, so throwaway types never leak."""
    registry = dict(Message.registry)
    monkeypatch.setattr(Message, "registry", registry)
    return registry
