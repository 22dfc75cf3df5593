"""Long checks on the whole shared data set (``python -m pytest -m slow``, not run by default)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path

from fpg_gym.core import metrics, poses
from fpg_gym.graph import FilteredPoseGraph
from fpg_gym.io import load_clips, load_default_clips
from fpg_gym.physics.ragdoll import Ragdoll

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def bandai_clips() -> list:
    return load_clips([shared_path("bandai_namco")], progress=False)


def test_every_bandai_namco_file_reads(bandai_clips: list) -> None:
    """All 3,065 takes (414,604 frames, see ../shared/data/README.md) read with sane bodies."""
    assert len(bandai_clips) == 3065
    assert sum(c.num_frames for c in bandai_clips) == 414604
    statures = np.array(
        [np.median(poses.stature(poses.bone_lengths(c.positions[::10]))) for c in bandai_clips]
    )
    assert np.all((statures > 1.4) & (statures < 2.0))


def test_whole_bandai_namco_graph(bandai_clips: list) -> None:
    graph = FilteredPoseGraph.build(bandai_clips, thres1=0.2, progress=False)
    assert graph.stats["poses"] == 414604
    assert 500 < graph.num_nodes < 5000
    # Undirected CSR: every edge stored both ways, no self loops.
    rows = np.repeat(np.arange(graph.num_nodes), graph.degree)
    pairs = set(zip(rows.tolist(), graph.indices.tolist(), strict=True))
    assert all((b, a) in pairs for a, b in pairs)
    assert not np.any(rows == graph.indices)


def test_ragdoll_tracks_every_default_clip_with_exact_bones() -> None:
    for clip in load_default_clips():
        body = Ragdoll(poses.bone_lengths(clip.positions[0]))
        try:
            lift = np.array([0.0, -clip.positions[:, :, 1].min() + body.foot_clearance, 0.0])
            targets = clip.positions + lift.astype(np.float32)
            out = [body.reset(targets[0])] + [body.track(p) for p in targets[1:]]
        finally:
            body.close()
        out_array = np.asarray(out)
        spread = np.abs(poses.bone_lengths(out_array) - body.model.bone_lengths).max()
        assert spread < 0.005, clip.name
        assert metrics.frame_error(targets, out_array).mean() < 0.03, clip.name
