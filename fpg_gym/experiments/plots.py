"""Plots and animations: skeletons, error histograms, cumulative curves, timings, GIFs.

Everything draws on :class:`matplotlib.figure.Figure` objects with the Agg canvas, so no display and
no global pyplot state are needed. Each ``plot_*`` function writes a PNG and returns its path.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from fpg_gym.core import metrics, skeleton
from fpg_gym.core.metrics import ERROR_BAND_EDGES
from fpg_gym.rendering import STATE_COLOURS

__all__ = [
    "ERROR_BAND_EDGES",
    "METHOD_COLOURS",
    "band_labels",
    "method_colours",
    "plot_cumulative",
    "plot_error_histogram",
    "plot_error_over_time",
    "plot_frame_times",
    "save_gif",
    "save_png",
    "skeleton_animation",
]

_PANEL_COLOURS = ("#3d5a80", "#e07a5f", "#2a9d8f", "#6d597a", "#bc4749")
#: Colours of the methods in the metric plots (matplotlib's tab10 then the light tab20 tones):
#: twenty distinct colours before any repeats.
METHOD_COLOURS: tuple[str, ...] = (
    "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
    "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
    "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5",
    "#c49c94", "#f7b6d2", "#c7c7c7", "#dbdb8d", "#9edae5",
)  # fmt: skip
_LINE_STYLES = ("-", "--", "-.", ":")


def band_labels(edges: Sequence[float] = ERROR_BAND_EDGES) -> list[str]:
    """Labels such as ``"0-5"``, ``"≥30"`` (centimetres) for error bands."""
    labels = []
    for low, high in itertools.pairwise(edges):
        labels.append(f"≥{100 * low:g}" if np.isinf(high) else f"{100 * low:g}-{100 * high:g}")
    return labels


def method_colours(names: Sequence[str]) -> dict[str, str]:
    """A colour per name, in order (pass the full method list so that subsets keep theirs)."""
    return {name: METHOD_COLOURS[i % len(METHOD_COLOURS)] for i, name in enumerate(names)}


def _save(figure: Figure, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    FigureCanvasAgg(figure)
    figure.savefig(path, dpi=110)
    return path


def _colour(index: int) -> str:
    return _PANEL_COLOURS[index % len(_PANEL_COLOURS)]


def _colours_for(names: Sequence[str], colours: Mapping[str, str] | None) -> dict[str, str]:
    chosen = method_colours(names)
    if colours:
        chosen.update({k: v for k, v in colours.items() if k in chosen})
    return chosen


def _figure(width: float, height: float, entries: int) -> tuple[Figure, Any, bool]:
    """A figure whose legend goes to the right of the axes when it has many entries."""
    outside = entries > 4
    figure = Figure(figsize=(width + (2.6 if outside else 0.0), height))
    return figure, figure.add_subplot(), outside


def _legend(axes: Any, outside: bool, **kwargs: Any) -> None:
    if outside:
        axes.legend(
            frameon=False, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, **kwargs
        )
    else:
        axes.legend(frameon=False, **kwargs)


def plot_error_histogram(
    errors: Mapping[str, np.ndarray],
    path: str | Path,
    *,
    edges: Sequence[float] = ERROR_BAND_EDGES,
    title: str = "Per-frame error (FPG Eq. 13) by band",
    colours: Mapping[str, str] | None = None,
) -> Path:
    """Grouped bars: share of frames (%) in each error band, one bar per method.

    Parameters
    ----------
    errors : mapping
        Method name -> per-frame errors in metres (all episodes concatenated).
    path : str or Path
        PNG to write.
    edges : sequence of float
        Band edges in metres (:data:`ERROR_BAND_EDGES`).
    colours : mapping, optional
        Method name -> colour (default :func:`method_colours` in the given order).
    """
    names = list(errors)
    palette = _colours_for(names, colours)
    figure, axes, outside = _figure(8, 4.2, len(names))
    labels = band_labels(edges)
    positions = np.arange(len(labels))
    width = 0.8 / max(1, len(names))
    for index, name in enumerate(names):
        share = 100.0 * metrics.band_shares(errors[name], edges)
        axes.bar(
            positions + (index - (len(names) - 1) / 2) * width,
            share,
            width,
            label=name,
            color=palette[name],
        )
    axes.set_xticks(positions, labels)
    axes.set_xlabel("per-frame error band (cm)")
    axes.set_ylabel("frames (%)")
    axes.set_title(title)
    _legend(axes, outside)
    axes.grid(axis="y", alpha=0.3)
    figure.tight_layout()
    return _save(figure, path)


def plot_cumulative(
    errors: Mapping[str, np.ndarray],
    path: str | Path,
    *,
    max_threshold: float = 0.4,
    title: str = "Frames with error above threshold (FPG Fig. 7)",
    colours: Mapping[str, str] | None = None,
) -> Path:
    """Share of frames (%) whose error is at least each threshold, one curve per method."""
    names = list(errors)
    palette = _colours_for(names, colours)
    thresholds = np.linspace(0.0, max_threshold, 161)
    figure, axes, outside = _figure(7, 4.2, len(names))
    for index, name in enumerate(names):
        above = 100.0 * metrics.frames_above(errors[name], thresholds)
        axes.plot(
            100 * thresholds,
            above,
            label=name,
            color=palette[name],
            lw=1.8,
            ls=_LINE_STYLES[(index // 10) % len(_LINE_STYLES)],
        )
    axes.axvline(20, color="grey", ls=":", lw=1)
    axes.text(20.5, 96, "Err0.2", color="grey", fontsize=8, va="top")
    axes.set_xlabel("error threshold (cm)")
    axes.set_ylabel("frames with error ≥ threshold (%)")
    axes.set_xlim(0, 100 * max_threshold)
    axes.set_ylim(0, 100)
    axes.set_title(title)
    _legend(axes, outside)
    axes.grid(alpha=0.3)
    figure.tight_layout()
    return _save(figure, path)


def plot_error_over_time(
    errors: Mapping[str, np.ndarray],
    path: str | Path,
    *,
    fps: float = 30.0,
    title: str = "Per-frame error over one episode",
    colours: Mapping[str, str] | None = None,
) -> Path:
    """Per-frame error (cm) against time (s), one line per method, for one episode."""
    names = list(errors)
    palette = _colours_for(names, colours)
    figure, axes, outside = _figure(9, 3.8, len(names) + 1)
    for name in names:
        values = np.asarray(errors[name])
        axes.plot(
            np.arange(len(values)) / fps, 100 * values, label=name, color=palette[name], lw=1.4
        )
    axes.axhline(20, color="grey", ls=":", lw=1, label="0.2 m (Err0.2)")
    axes.set_xlabel("time (s)")
    axes.set_ylabel("error (cm)")
    axes.set_ylim(bottom=0)
    axes.set_title(title)
    if outside:
        _legend(axes, outside)
    else:
        axes.legend(frameon=False, ncols=min(5, len(names) + 1))
    axes.grid(alpha=0.3)
    figure.tight_layout()
    return _save(figure, path)


def plot_frame_times(
    milliseconds: Mapping[str, np.ndarray],
    path: str | Path,
    *,
    title: str = "Computation time per frame",
    colours: Mapping[str, str] | None = None,
) -> Path:
    """Distribution of per-frame computation time (ms) per method, as box plots on a log axis.

    Boxes span the quartiles, whiskers 1.5 IQR; outliers are not drawn.
    """
    names = list(milliseconds)
    palette = _colours_for(names, colours)
    figure = Figure(figsize=(max(7.0, 0.75 * len(names) + 2.0), 4.6))
    axes = figure.add_subplot()
    data = [np.maximum(np.asarray(milliseconds[name], dtype=float), 1e-3) for name in names]
    boxes = axes.boxplot(data, tick_labels=names, showfliers=False, patch_artist=True)
    for patch, name in zip(boxes["boxes"], names, strict=True):
        patch.set_facecolor(palette[name])
        patch.set_alpha(0.6)
    for median in boxes["medians"]:
        median.set_color("black")
    axes.set_yscale("log")
    from matplotlib.ticker import FuncFormatter

    axes.yaxis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axes.set_ylabel("time per frame (ms, log scale)")
    axes.set_xlabel("method")
    if len(names) > 4 or max((len(n) for n in names), default=0) > 12:
        axes.tick_params(axis="x", labelrotation=30)
        for label in axes.get_xticklabels():
            label.set_horizontalalignment("right")
    axes.set_title(title)
    axes.grid(axis="y", alpha=0.3, which="both")
    figure.tight_layout()
    return _save(figure, path)


# --------------------------------------------------------------------------- skeleton drawing


def _segments(pose: np.ndarray, horizontal: int) -> np.ndarray:
    """Bone segments ``(19, 2, 2)`` projected on (horizontal axis, Y)."""
    ends = pose[skeleton.BONES]  # (19, 2, 3)
    return ends[..., [horizontal, 1]]


def skeleton_animation(
    panels: Mapping[str, np.ndarray],
    *,
    states: np.ndarray | None = None,
    states_panel: str | None = None,
    fps: float = 30.0,
    size: tuple[float, float] | None = None,
    view: str = "front",
    title: str = "",
) -> list[np.ndarray]:
    """Render side-by-side skeleton panels frame by frame into RGB arrays.

    Parameters
    ----------
    panels : mapping
        Panel title -> poses ``(T, 20, 3)`` (same T for every panel), metres.
    states : ndarray (T, 20), optional
        Kinect tracking states to colour the joints of ``states_panel`` (green tracked, orange
        inferred, red not tracked).
    states_panel : str, optional
        Which panel the states belong to (the first one by default).
    view : {"front", "side"}
        Project on X-Y (seen from +Z) or Z-Y.

    Returns
    -------
    list of ndarray
        ``(H, W, 3)`` uint8 frames.
    """
    from matplotlib.collections import LineCollection

    names = list(panels)
    sequences = [np.asarray(panels[name], dtype=np.float64) for name in names]
    count = len(sequences[0])
    if any(len(s) != count for s in sequences):
        raise ValueError("panels: every sequence must have the same number of frames")
    horizontal = 0 if view == "front" else 2
    everything = np.concatenate([s.reshape(-1, 3) for s in sequences])
    low, high = everything.min(0), everything.max(0)
    centre = (low + high) / 2
    half = max(float((high - low)[[horizontal, 1]].max()) / 2 + 0.1, 0.5)
    figure = Figure(figsize=size or (3.2 * len(names), 3.8))
    canvas = FigureCanvasAgg(figure)
    if title:
        figure.suptitle(title)
    collections = []
    scatters = []
    time_text = figure.text(0.01, 0.01, "", fontsize=8)
    states_index = names.index(states_panel) if states_panel else 0
    for index, name in enumerate(names):
        axes = figure.add_subplot(1, len(names), index + 1)
        axes.set_xlim(centre[horizontal] - half, centre[horizontal] + half)
        axes.set_ylim(centre[1] - half, centre[1] + half)
        axes.set_aspect("equal")
        axes.set_title(name, fontsize=10)
        axes.set_xlabel("X (m)" if view == "front" else "Z (m)", fontsize=8)
        axes.tick_params(labelsize=7)
        if index == 0:
            axes.set_ylabel("Y (m)", fontsize=8)
        lines = LineCollection(
            list(_segments(sequences[index][0], horizontal)), colors=_colour(index), linewidths=2.5
        )
        axes.add_collection(lines)
        collections.append(lines)
        scatters.append(
            axes.scatter(
                sequences[index][0, :, horizontal], sequences[index][0, :, 1], s=10, c="k", zorder=3
            )
        )
    figure.tight_layout()
    frames: list[np.ndarray] = []
    for t in range(count):
        for index, sequence in enumerate(sequences):
            collections[index].set_segments(list(_segments(sequence[t], horizontal)))
            scatters[index].set_offsets(sequence[t][:, [horizontal, 1]])
            if states is not None and index == states_index:
                scatters[index].set_color([STATE_COLOURS.get(int(s), "k") for s in states[t]])
        time_text.set_text(f"t = {t / fps:5.2f} s")
        canvas.draw()
        frames.append(np.asarray(canvas.buffer_rgba())[..., :3].copy())
    return frames


def save_gif(path: str | Path, frames: Sequence[np.ndarray], *, fps: float = 30.0) -> Path:
    """Write RGB frames as a looping animated GIF."""
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), extension=".gif", duration=1000.0 / fps, loop=0)
    return path


def save_png(path: str | Path, image: np.ndarray) -> Path:
    """Write one RGB(A) uint8 image as PNG."""
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.asarray(image, dtype=np.uint8), extension=".png")
    return path
