"""Plots write non-blank PNGs and GIFs of the expected size."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np

from fpg_gym.core import poses
from fpg_gym.experiments import plots
from fpg_gym.io import load_default_clips


def _not_blank(image: np.ndarray) -> bool:
    return float(image[..., :3].std()) > 5.0


def test_metric_plots(tmp_path: Path, rng: np.random.Generator) -> None:
    errors = {
        "raw": np.abs(rng.normal(0.15, 0.08, 300)),
        "fpg": np.abs(rng.normal(0.08, 0.03, 300)),
    }
    written = [
        plots.plot_error_histogram(errors, tmp_path / "hist.png"),
        plots.plot_cumulative(errors, tmp_path / "cumulative.png"),
        plots.plot_error_over_time(errors, tmp_path / "time.png"),
        plots.plot_frame_times(
            {"raw": rng.random(50), "fpg": 5 * rng.random(50)}, tmp_path / "ms.png"
        ),
    ]
    for path in written:
        image = iio.imread(path)
        assert image.shape[0] > 300 and image.shape[1] > 600
        assert _not_blank(image)


def test_band_labels() -> None:
    assert plots.band_labels() == ["0-5", "5-10", "10-15", "15-20", "20-30", "≥30"]


def test_skeleton_animation_and_gif(tmp_path: Path) -> None:
    clip = load_default_clips(["punch"])[0]
    normalised, _ = poses.normalise(clip.positions[:6])
    states = np.full((6, 20), 2, dtype=np.int8)
    states[:, 7] = 0
    frames = plots.skeleton_animation(
        {"Kinect": normalised + 0.02, "reconstruction": normalised}, states=states
    )
    assert len(frames) == 6
    assert frames[0].ndim == 3 and frames[0].shape[2] == 3
    assert _not_blank(frames[0])
    gif = plots.save_gif(tmp_path / "anim.gif", frames, fps=10)
    assert iio.imread(gif).shape[0] == 6
