"""Reading mocap clips by file name (BVH, DeepMimic, positions ``.npz``) and the embedded default.

:func:`read_clip` picks the reader from the file name (``.bvh``/``.bvh.gz``: BVH, ``.npz``:
positions, ``.txt``/``.json``: DeepMimic) unless ``format`` says otherwise. :func:`load_clips`
expands folders and the word ``default`` (the 15 DeepMimic clips in the pybullet wheel), reads
in parallel processes with a progress bar, and returns the clips in a stable order.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path

from tqdm.auto import tqdm

from fpg_gym.core.defaults import DEFAULT_HOLDOUT_CLIPS
from fpg_gym.core.errors import DataFormatError, FpgGymError
from fpg_gym.io.bvh import BANDAI_NAMCO_MAP, JointSource, read_bvh
from fpg_gym.io.clip import Clip
from fpg_gym.io.deepmimic import DEFAULT_CLIP_NAMES, load_default_clips, read_deepmimic
from fpg_gym.io.positions import read_positions

__all__ = [
    "DEFAULT_INPUT",
    "MOCAP_FORMATS",
    "expand_inputs",
    "find_mocap_files",
    "load_clips",
    "mocap_format",
    "read_clip",
    "resolve_clips",
]

#: Mocap formats :func:`read_clip` understands.
MOCAP_FORMATS: tuple[str, ...] = ("bvh", "deepmimic", "positions")
DEFAULT_INPUT = "default"


def mocap_format(path: str | Path) -> str:
    """The mocap format of a file, from its name.

    Raises
    ------
    ValueError
        If the extension is not one of ``.bvh``, ``.bvh.gz``, ``.npz``, ``.txt``, ``.json``.
    """
    name = Path(path).name.lower()
    if name.endswith((".bvh", ".bvh.gz")):
        return "bvh"
    if name.endswith(".npz"):
        return "positions"
    if name.endswith((".txt", ".json")):
        return "deepmimic"
    raise ValueError(
        f"{path}: unknown mocap format; expected .bvh, .bvh.gz, .npz (positions) or "
        ".txt/.json (DeepMimic), or pass format= one of " + ", ".join(MOCAP_FORMATS)
    )


def read_clip(
    path: str | Path,
    *,
    format: str | None = None,
    joint_map: Mapping[str, JointSource] | None = None,
    units: str = "auto",
) -> Clip:
    """Read one mocap file as a Kinect-20 clip at 30 Hz.

    Parameters
    ----------
    path : str or Path
    format : {"bvh", "deepmimic", "positions"}, optional
        Overrides detection by file name.
    joint_map : mapping, optional
        BVH joint map (Bandai Namco's by default); ignored by other formats.
    units : str
        BVH length unit ("auto", "m", "cm", "mm").
    """
    kind = format or mocap_format(path)
    if kind == "bvh":
        return read_bvh(path, joint_map or BANDAI_NAMCO_MAP, units=units)
    if kind == "deepmimic":
        return read_deepmimic(path)
    if kind == "positions":
        return read_positions(path)
    raise ValueError(f"format: expected one of {', '.join(MOCAP_FORMATS)}, got {format!r}")


def _is_mocap_file(path: Path) -> bool:
    try:
        mocap_format(path)
    except ValueError:
        return False
    return not path.name.startswith(".")


def expand_inputs(
    inputs: Iterable[str | Path], accept: Callable[[Path], bool], kind: str
) -> list[Path]:
    """Files named by ``inputs``: files as given, folders expanded (recursively, sorted) into
    the files ``accept`` takes.

    Raises
    ------
    FileNotFoundError
        If an input does not exist or a folder holds no accepted file (``kind`` names them).
    """
    files: list[Path] = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.rglob("*") if p.is_file() and accept(p))
            if not found:
                raise FileNotFoundError(f"{path}: folder holds no {kind}")
            files.extend(found)
        elif path.is_file():
            files.append(path)
        else:
            raise FileNotFoundError(f"{path}: no such file or folder")
    return files


def find_mocap_files(inputs: Iterable[str | Path]) -> list[Path]:
    """Expand folders (recursively, sorted) into the mocap files they hold.

    Raises
    ------
    FileNotFoundError
        If an input does not exist or a folder holds no mocap file.
    """
    return expand_inputs(inputs, _is_mocap_file, ".bvh, .bvh.gz, .npz or .txt file")


def _read_for_pool(path: Path, units: str, joint_map: Mapping[str, JointSource] | None) -> Clip:
    """:func:`read_clip` in a reader process: any failure comes back naming the file (the
    project's errors pickle with their message; others are wrapped)."""
    try:
        return read_clip(path, joint_map=joint_map, units=units)
    except FpgGymError:
        raise
    except Exception as error:
        raise DataFormatError(
            path, f"cannot be read ({type(error).__name__}: {' '.join(str(error).split())})"
        ) from None


def load_clips(
    inputs: Sequence[str | Path],
    *,
    workers: int | None = None,
    progress: bool = True,
    units: str = "auto",
    joint_map: Mapping[str, JointSource] | None = None,
) -> list[Clip]:
    """Read every clip named by ``inputs`` (files, folders, or ``"default"``).

    Parameters
    ----------
    inputs : sequence of str or Path
        Mocap files, folders searched recursively, or the word ``"default"`` for the embedded
        DeepMimic clips.
    workers : int, optional
        Reader processes; ``os.cpu_count()`` by default, 1 reads in this process.
    progress : bool
        Show a tqdm progress bar on stderr.
    units, joint_map
        Passed to :func:`read_clip` for BVH files.

    Raises
    ------
    DataFormatError
        The first bad file, named in the message.
    """

    # Each input becomes a list of ready clips ("default") or of files to read, in input order.
    groups: list[list[Clip] | list[Path]] = []
    for item in inputs:
        groups.append(
            load_default_clips() if str(item) == DEFAULT_INPUT else find_mocap_files([item])
        )
    paths = [p for group in groups for p in group if isinstance(p, Path)]
    read: dict[Path, Clip] = {}
    workers = workers or os.cpu_count() or 1
    reader = partial(_read_for_pool, units=units, joint_map=joint_map)
    bar = tqdm(
        total=len(paths), desc="reading mocap", unit="file", disable=not progress or not paths
    )
    try:
        if workers <= 1 or len(paths) < 4:
            for path in paths:
                read[path] = reader(path)
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                chunk = max(1, min(32, len(paths) // (workers * 8)))
                for path, clip in zip(paths, pool.map(reader, paths, chunksize=chunk), strict=True):
                    read[path] = clip
                    bar.update()
    finally:
        bar.close()
    return [read[item] if isinstance(item, Path) else item for group in groups for item in group]


def resolve_clips(
    items: Sequence[str], units: str = "auto", progress: bool = False
) -> tuple[list[Clip], list[str]]:
    """Read the clips named by ``--clips`` (as ``fpg-gym compare`` takes them), in order.

    ``default`` means the embedded held-out clips; ``walk`` / ``default:walk`` an embedded clip;
    anything else a mocap file or folder.

    Returns
    -------
    clips : list of Clip
    embedded : list of str
        Names of the embedded clips among them (the default graph leaves these out).
    """
    clips: list[Clip] = []
    embedded: list[str] = []
    files: list[str] = []

    def flush_files() -> None:
        if files:
            clips.extend(load_clips(list(files), units=units, progress=progress))
            files.clear()

    for item in items:
        text = str(item)
        name = text.removeprefix("default:")
        if text == "default":
            flush_files()
            clips.extend(load_default_clips(list(DEFAULT_HOLDOUT_CLIPS)))
            embedded.extend(DEFAULT_HOLDOUT_CLIPS)
        elif name in DEFAULT_CLIP_NAMES and not Path(text).exists():
            flush_files()
            clips.extend(load_default_clips([name]))
            embedded.append(name)
        elif text.startswith("default:"):
            raise ValueError(
                f"--clips: unknown embedded clip {name!r}; expected one of "
                + ", ".join(DEFAULT_CLIP_NAMES)
            )
        else:
            files.append(text)
    flush_files()
    return clips, sorted(set(embedded))
