"""Drawing the env's frames: Kinect input (joints coloured by tracking state) beside the
reconstruction, as the sensor sees them; and a matplotlib window for ``render_mode="human"``.

Pillow draws the images (a matplotlib dependency, cheap to import). ``pyplot`` is imported only
when a window opens: it costs about half a second and needs a display backend.
"""

from __future__ import annotations

import functools
import warnings
from typing import Any

import numpy as np
from PIL import Image, ImageDraw

from fpg_gym.core import skeleton
from fpg_gym.core.metrics import frame_error

__all__ = ["PANEL", "STATE_COLOURS", "HumanWindow", "render_panels"]

#: Joint colours by tracking state: tracked, inferred, not tracked.
STATE_COLOURS = {
    skeleton.TRACKED: "#2a9d4b",
    skeleton.INFERRED: "#f4a020",
    skeleton.NOT_TRACKED: "#d62828",
}
#: Side of one panel in pixels (an image is two panels wide).
PANEL = 320
_NON_INTERACTIVE_BACKENDS = {"agg", "pdf", "ps", "svg", "pgf", "cairo", "template"}


@functools.cache
def _state_rgb() -> dict[int, tuple[int, int, int]]:
    """:data:`STATE_COLOURS` as RGB tuples."""
    return {
        s: (int(c[1:3], 16), int(c[3:5], 16), int(c[5:7], 16)) for s, c in STATE_COLOURS.items()
    }


def _draw_skeleton(
    draw: ImageDraw.ImageDraw,
    pose: np.ndarray,
    centre: np.ndarray,
    offset: int,
    colour: tuple[int, int, int],
    states: np.ndarray | None,
    half_m: float = 1.2,
) -> None:
    """Draw a camera-space pose as the sensor sees it (image x = -X, y = -Y)."""
    scale = PANEL / (2 * half_m)
    u = offset + PANEL / 2 - (np.asarray(pose[:, 0]) - centre[0]) * scale
    v = PANEL / 2 - (np.asarray(pose[:, 1]) - centre[1]) * scale
    points = np.stack([u, v], axis=1).tolist()
    for parent, child in skeleton.BONES:
        draw.line([tuple(points[parent]), tuple(points[child])], fill=colour, width=3)
    for j, (x, y) in enumerate(points):
        fill = colour if states is None else _state_rgb().get(int(states[j]), colour)
        draw.ellipse([x - 3, y - 3, x + 3, y + 3], fill=fill)


def render_panels(
    positions: np.ndarray | None,
    states: np.ndarray | None,
    reconstruction: np.ndarray | None,
    truth: np.ndarray | None,
    *,
    centre: np.ndarray | None = None,
    caption: str = "",
) -> np.ndarray:
    """A ``(PANEL, 2 * PANEL, 3)`` uint8 image: the input (left) and the reconstruction (right).

    Parameters
    ----------
    positions, states : ndarray, shape (20, 3) and (20,), or None
        The Kinect frame (None: a "call reset() first" image).
    reconstruction, truth : ndarray, shape (20, 3), or None
        Drawn when given (the truth in light grey behind both panels).
    centre : ndarray, shape (2,), optional
        Camera-space (X, Y) at the panels' centre (the origin by default).
    caption : str
        Text at the bottom; the frame's error is added when both poses are known.
    """
    image = Image.new("RGB", (2 * PANEL, PANEL), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    if positions is None:
        draw.text((8, 8), "call reset() first", fill=(0, 0, 0))
        return np.asarray(image)
    centre = np.zeros(2) if centre is None else centre
    panels = [
        ("Kinect input", positions, states, (60, 60, 60)),
        ("reconstruction", reconstruction, None, (40, 90, 160)),
    ]
    for index, (title, pose, pose_states, colour) in enumerate(panels):
        offset = index * PANEL
        if truth is not None:
            _draw_skeleton(draw, truth, centre, offset, (200, 200, 200), None)
        if pose is not None:
            _draw_skeleton(draw, pose, centre, offset, colour, pose_states)
        draw.text((offset + 8, 6), title, fill=(0, 0, 0))
        draw.line([(offset, 0), (offset, PANEL)], fill=(180, 180, 180))
    if truth is not None and reconstruction is not None:
        caption += f"   error {1000 * float(frame_error(truth, reconstruction)[0]):.0f} mm"
    draw.text((8, PANEL - 16), caption, fill=(0, 0, 0))
    return np.asarray(image)


class HumanWindow:
    """A matplotlib window showing rendered frames (``render_mode="human"``).

    Without a display (a non-interactive backend) the first :meth:`show` warns once and nothing
    is shown.

    Parameters
    ----------
    fps : float
        Frames per second to pace the window at.
    """

    def __init__(self, fps: float) -> None:
        self.fps = float(fps)
        self._figure: Any = None
        self._image: Any = None
        self._disabled = False

    def show(self, frame: np.ndarray) -> None:
        """Draw ``frame`` (an RGB image) and pause for one frame's time."""
        if self._disabled:
            return
        import matplotlib
        import matplotlib.pyplot as plt

        if self._figure is None:
            backend = str(matplotlib.get_backend()).lower()
            if backend in _NON_INTERACTIVE_BACKENDS:
                warnings.warn(
                    f"render_mode='human' needs a display, but matplotlib uses the "
                    f"non-interactive backend {backend!r}: nothing is shown. Use "
                    "render_mode='rgb_array' (e.g. to save a GIF) or run with a display.",
                    UserWarning,
                    stacklevel=3,
                )
                self._disabled = True
                return
            self._figure, axes = plt.subplots(figsize=(8, 4))
            axes.axis("off")
            self._image = axes.imshow(frame)
            self._figure.tight_layout()
            plt.show(block=False)
        else:
            self._image.set_data(frame)
        plt.pause(1.0 / self.fps)

    def close(self) -> None:
        """Close the window (idempotent)."""
        if self._figure is not None:
            import matplotlib.pyplot as plt

            plt.close(self._figure)
            self._figure = None
            self._image = None
