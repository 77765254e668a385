"""Registers the test-only nodes (``synthetic.*``) in every test process."""

from __future__ import annotations

import tests.synthetic_nodes  # noqa: F401  (registers synthetic.source, .relay, .merge, .sink)
