"""sim.free_bubble: the bubbles' no-contact frames, averaged over the ToF noise."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from perception.classify.preprocess import FreeBubble
from sim.free_bubble import free_bubble_frames, main


def test_free_frames_are_the_rest_cap_with_its_unseen_rim(tmp_path: Path, capsys) -> None:
    arrays = free_bubble_frames(frames=4)
    for side in ("left", "right"):
        depth, ir = arrays[f"depth_{side}_m"], arrays[f"ir_{side}"]
        valid = np.isfinite(depth)
        # The rim's grazing pixels are lost at rest too (about 6%), the rest is seen.
        assert 0.02 < 1 - valid.mean() < 0.12
        assert 0.03 < float(depth[valid].min()) and float(depth[valid].max()) < 0.08
        assert (ir[valid] > 0).mean() > 0.99
    # Averaged over the noise: the two bubbles' frames are alike but not noise-equal.
    assert np.nanmedian(np.abs(arrays["depth_left_m"] - arrays["depth_right_m"])) < 3e-4
    assert main([str(tmp_path / "free.npz"), "--frames", "2"]) == 0
    assert "wrote" in capsys.readouterr().out
    with np.load(tmp_path / "free.npz", allow_pickle=False) as saved:
        free = FreeBubble.from_arrays(dict(saved), "free.npz")
    assert free.depth_left_m.shape == arrays["depth_left_m"].shape
    with pytest.raises(ValueError, match="frames must be >= 1"):
        free_bubble_frames(frames=0)
