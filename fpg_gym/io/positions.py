"""Plain positions files: ``.npz`` with ``positions`` (T, 20, 3) metres Y-up and ``fps``."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.outputs import save_npz
from fpg_gym.io.clip import Clip
from fpg_gym.io.files import check_input_file
from fpg_gym.io.npz import check_npz
from fpg_gym.io.plausibility import check_plausible


def read_positions(path: str | Path) -> Clip:
    """Read a positions ``.npz`` file as a clip.

    The archive holds ``positions``, float array ``(T, 20, 3)`` in metres, Y up, Kinect-20 joint
    order (:data:`fpg_gym.core.skeleton.JOINT_NAMES`), and ``fps``, a positive scalar. An optional
    ``name`` (string scalar) names the clip; the file stem is used otherwise. Pickled objects are
    refused.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    DataFormatError
        If a key is missing, a shape is wrong, or a value is NaN/inf; or the positions are not
        a person in metres at a real frame rate
        (:func:`fpg_gym.io.plausibility.check_plausible`).
    """
    path = check_input_file(path)
    if not zipfile.is_zipfile(path):
        raise DataFormatError(path, "not a readable .npz archive (not a zip file)")
    # Forged array headers, pickled arrays, archives declaring more than the memory ceiling:
    # refused before numpy inflates anything.
    check_npz(path, shapes={"positions": ("T", skeleton.NUM_JOINTS, 3), "name": ()})
    try:
        with np.load(path, allow_pickle=False) as archive:
            keys = set(archive.files)
            for key in ("positions", "fps"):
                if key not in keys:
                    raise DataFormatError(
                        path, f"missing key {key!r} (found {sorted(keys)})", field=key
                    )
            positions = np.asarray(archive["positions"])
            fps_array = np.asarray(archive["fps"])
            name = str(archive["name"]) if "name" in keys else path.stem
    except (zipfile.BadZipFile, OSError, EOFError, zlib.error) as error:
        raise DataFormatError(path, f"not a readable .npz archive ({error})") from None
    except ValueError as error:  # pickled arrays
        raise DataFormatError(path, f"unreadable array ({error})") from None
    if positions.ndim != 3 or positions.shape[1:] != (skeleton.NUM_JOINTS, 3):
        raise DataFormatError(
            path, f"expected shape (T, 20, 3), got {positions.shape}", field="positions"
        )
    if len(positions) == 0:
        raise DataFormatError(path, "the clip has no frames", field="positions")
    if not np.issubdtype(positions.dtype, np.number):
        raise DataFormatError(path, f"expected numbers, got {positions.dtype}", field="positions")
    with np.errstate(invalid="ignore", over="ignore"):
        finite = np.isfinite(positions.astype(np.float32))  # float32 overflow is inf too
    if not np.all(finite):
        frame = int(np.argwhere(~finite)[0, 0])
        raise DataFormatError(
            path, f"NaN or inf at frame {frame} (or a value beyond float32)", field="positions"
        )
    if fps_array.size != 1 or not np.issubdtype(fps_array.dtype, np.number):
        raise DataFormatError(path, f"expected a number, got {fps_array!r}", field="fps")
    fps = float(fps_array.reshape(()))
    if not (np.isfinite(fps) and fps > 0):
        raise DataFormatError(path, f"expected a positive frame rate, got {fps}", field="fps")
    check_plausible(path, positions, fps=fps)
    return Clip(
        name=name,
        positions=positions.astype(np.float32),
        fps=fps,
        source=str(path),
        metadata={"format": "positions"},
    )


def write_positions(path: str | Path, clip: Clip) -> Path:
    """Write a clip as a positions ``.npz`` file readable by :func:`read_positions`."""
    path = Path(path)
    arrays = {
        "positions": clip.positions.astype(np.float32),
        "fps": np.float64(clip.fps),
        "name": np.array(clip.name),
    }
    return save_npz(path, arrays)
