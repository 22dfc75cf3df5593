"""A comparison's output folder: the manifest of the files it wrote, the resumable
``results.csv`` and the per-frame arrays."""

from __future__ import annotations

import csv
import glob
import io
import json
import math
import os
import zipfile
import zlib
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core import skeleton
from fpg_gym.core.errors import FpgGymError, OutputError
from fpg_gym.core.outputs import save_npz, write_text
from fpg_gym.experiments.config import safe_name
from fpg_gym.io.npz import check_npz

try:
    import fcntl
except ImportError:  # pragma: no cover - not Unix: folders are not locked
    fcntl = None  # type: ignore[assignment]

#: Columns of ``results.csv`` (one row per episode and method).
CSV_FIELDS: tuple[str, ...] = (
    "episode",
    "clip",
    "scenario",
    "seed",
    "method",
    "base",
    "selector",
    "optimizer",
    "ragdoll",
    "budget",
    "frames",
    "input_frames",
    "interrupted",
    "mean_error_m",
    "std_error_m",
    "median_error_m",
    "p95_error_m",
    "err02_pct",
    "input_mean_error_m",
    "mpjpe_m",
    "root_mpjpe_m",
    "pa_mpjpe_m",
    "occluded_mpjpe_m",
    "visible_mpjpe_m",
    "occluded_joint_frames",
    "input_mpjpe_m",
    "bone_length_error_mm",
    "bone_length_spread_mm",
    "jitter_ms2",
    "truth_jitter_ms2",
    "ms_median",
    "ms_p95",
    "ms_mean",
    "evaluations_mean",
    "energy_mean",
    "recoveries",
    "ragdoll_divergences",
    "seconds",
    "lag_frames",
    "lag_ms",
    "settled_bone_spread_mm",
    "bone_changes_after_settling",
)


def read_rows(path: Path) -> list[dict[str, str]]:
    """The rows of ``results.csv`` as dicts by column; rows whose field count differs from the
    header's (a damaged file) are left out, undecodable bytes replaced."""
    if not path.is_file():
        return []
    text = path.read_bytes().decode("utf-8", errors="replace").replace("\0", "")
    rows = list(csv.reader(io.StringIO(text, newline="")))
    if not rows:
        return []
    header = rows[0]
    return [dict(zip(header, row, strict=True)) for row in rows[1:] if len(row) == len(header)]


def repair_results(
    path: Path,
    say: Callable[[str], None],
    drop_episodes: Iterable[str] = (),
    drop_methods: Iterable[str] = (),
    drop_tasks: Iterable[tuple[str, str]] = (),
) -> None:
    """Make ``results.csv`` safe to append to: drop a torn last row (a kill during a write
    leaves a row without its line end, which the next row would be glued to), rows whose
    field count is wrong or that name no task, all but the last row of a task, and the rows
    of ``drop_episodes`` and ``drop_methods`` (stale episodes, methods whose model changed)
    and of ``drop_tasks`` (``(episode, method)`` pairs whose per-frame file is missing or
    damaged); rewrite it with
    the header :data:`CSV_FIELDS` (columns matched by name) when its header differs. Warns
    (``say``) about every row dropped but the stale ones. The file is rewritten atomically,
    and only when something changed."""
    if not path.is_file():
        return
    raw = path.read_bytes()
    if not raw:
        return
    changed = False
    if raw.endswith(b"\r"):  # the row is whole; only its "\n" is missing
        raw += b"\n"
        changed = True
    if not raw.endswith(b"\n"):
        cut = raw.rfind(b"\n") + 1
        torn = raw[cut:].decode("utf-8", errors="replace")
        line = raw.count(b"\n") + 1
        say(
            f"warning: {path}, line {line}: the last row was cut off (an interrupted write); "
            f"dropped it ({torn[:60]!r}); its task runs again"
        )
        raw = raw[:cut]
        changed = True
    text = raw.decode("utf-8", errors="replace")
    if "\0" in text:
        text = text.replace("\0", "")
        changed = True
    rows = list(csv.reader(io.StringIO(text, newline="")))
    if not rows:
        path.write_bytes(b"")
        return
    header, body = rows[0], rows[1:]
    if tuple(header) != CSV_FIELDS:
        changed = True
    if not {"episode", "method"} <= set(header):
        say(f"warning: {path}: not a results table (no episode and method columns); its rows "
            "are dropped and their tasks run again")  # fmt: skip
        body = []
    drop, drop_method, drop_task = set(drop_episodes), set(drop_methods), set(drop_tasks)
    kept: list[dict[str, str]] = []
    for number, row in enumerate(body, start=2):
        if len(row) != len(header):
            say(
                f"warning: {path}, line {number}: expected {len(header)} fields, got {len(row)}; "
                "dropped the row; its task runs again"
            )
            changed = True
            continue
        record = dict(zip(header, row, strict=True))
        task = (record.get("episode", ""), record.get("method", ""))
        if not all(task) or task[0] in drop or task[1] in drop_method or task in drop_task:
            changed = True
            continue
        kept.append(record)
    last = {(r.get("episode"), r.get("method")): i for i, r in enumerate(kept)}
    if len(last) < len(kept):  # a task's row twice (a rerun after an interruption): the last
        kept = [r for i, r in enumerate(kept) if last[(r.get("episode"), r.get("method"))] == i]
        changed = True
    if not changed:
        return
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=list(CSV_FIELDS), extrasaction="ignore")
    writer.writeheader()
    for record in kept:
        writer.writerow({k: record.get(k, "") for k in CSV_FIELDS})
    write_text(path, buffer.getvalue())


#: The file listing what compare wrote in its output folder.
MANIFEST_NAME = "manifest.txt"


_MANIFEST_HEADER = (
    "# fpg-gym compare manifest v1: the files fpg-gym compare wrote in this folder, one relative "
    "path per line; compare --fresh deletes these and nothing else\n"
)


class Manifest:
    """``manifest.txt``: every file compare writes in its folder, listed (appended and flushed)
    before the file is written, so that ``--fresh`` can delete exactly those files.

    It is also the folder's lock: a run holds an exclusive lock on it (``flock``, released
    when the process ends, even by ``kill -9``) from :func:`claim_folder` to :meth:`close`,
    and a second run on the same folder is refused instead of writing rows beside the first's.

    Parameters
    ----------
    out : Path
        The folder (it exists).
    adopt : bool
        Accept to list files that are already there (a folder of an earlier fpg-gym without a
        manifest); otherwise :meth:`add` refuses a file that exists unlisted (the user's).

    Raises
    ------
    OutputError
        Another run holds the folder.
    """

    def __init__(self, out: Path, *, adopt: bool = False) -> None:
        self.out = out
        self.path = out / MANIFEST_NAME
        self.adopt = adopt
        self._lock = _lock_file(self.path, out)
        self.listed: set[str] = set(self.entries())
        if self.path.stat().st_size == 0:
            self.path.write_text(_MANIFEST_HEADER, encoding="utf-8")

    def close(self) -> None:
        """Release the folder's lock."""
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None

    def __enter__(self) -> Manifest:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def entries(self) -> list[str]:
        """The listed relative paths (a torn last line, from a kill during a write, is not
        trusted)."""
        if not self.path.is_file():
            return []
        text = self.path.read_text(encoding="utf-8", errors="replace")
        lines = text.split("\n")[:-1]  # the last piece lacks its line end: torn or empty
        return [line for line in lines if line and not line.startswith("#")]

    def add(self, *paths: Path) -> None:
        """List ``paths`` (files inside the folder) before they are written.

        Raises
        ------
        OutputError
            A path is a file compare did not write (it exists, unlisted): compare never
            overwrites it (nor, then, deletes it with ``--fresh``).
        """
        new = []
        for path in paths:
            relative = path.relative_to(self.out).as_posix()
            if relative in self.listed:
                continue
            if not self.adopt and (path.exists() or path.is_symlink()):
                raise OutputError(
                    f"--out {self.out}: {relative} is there and fpg-gym compare did not write "
                    f"it (not in {MANIFEST_NAME}); compare would overwrite it: move it away, "
                    "or choose another --out"
                )
            new.append(relative)
        if new:
            try:
                with self.path.open("a", encoding="utf-8") as handle:
                    handle.write("".join(f"{r}\n" for r in new))
                    handle.flush()
                    os.fsync(handle.fileno())
            except OSError as error:
                raise OutputError(f"{self.path}: cannot write ({error.strerror})") from None
            self.listed.update(new)

    def delete_listed(self) -> int:
        """Delete the listed files that are regular files inside the folder (never a link, never
        anything outside it), then the folders they leave empty; empty the list. Returns the
        number of files deleted."""
        root = self.out.resolve()
        deleted = 0
        folders: set[Path] = set()
        for relative in self.entries():
            path = self.out / relative
            try:
                real = path.resolve()
            except (OSError, ValueError, RuntimeError):  # NUL bytes, link loops
                continue
            if not real.is_relative_to(root) or real == root or path.is_symlink():
                continue
            # The file, and temporary files of it left by a kill during a write
            # (fpg_gym.core.outputs.atomic_path names them ".NAME.PID.HEX.tmp").
            pattern = f".{glob.escape(real.name)}.*.tmp"
            leftovers = [p for p in real.parent.glob(pattern) if p.is_file() and not p.is_symlink()]
            for leftover in leftovers:
                leftover.unlink()
            if real.is_file() or leftovers:
                if real.is_file():
                    real.unlink()
                deleted += 1
                parent = real.parent
                while parent != root and parent.is_relative_to(root):
                    folders.add(parent)
                    parent = parent.parent
        for folder in sorted(folders, key=lambda p: len(p.parts), reverse=True):
            try:
                folder.rmdir()  # only when empty
            except OSError:
                pass
        self.path.write_text(_MANIFEST_HEADER, encoding="utf-8")
        self.listed = set()
        return deleted


def _is_legacy_compare_folder(out: Path) -> bool:
    """A folder written by an fpg-gym compare of before the manifest (config.json with a
    resume key beside results.csv)."""
    try:
        config = json.loads((out / "config.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(config, dict) and "resume_key" in config and (out / "results.csv").is_file()


def claim_folder(out: Path, fresh: bool, say: Callable[[str], None]) -> Manifest:
    """The output folder's manifest, after checking that compare may write (and with
    ``fresh``, delete) there.

    Raises
    ------
    OutputError
        ``out`` is a file, or a folder holding files compare did not write (no manifest),
        or ``fresh`` is asked for a folder of an earlier fpg-gym without a manifest.
    """
    if out.exists() and not out.is_dir():
        raise OutputError(f"--out {out}: is a file; expected a folder")
    if out.is_dir() and not (out / MANIFEST_NAME).is_file() and any(out.iterdir()):
        if not _is_legacy_compare_folder(out):
            raise OutputError(
                f"--out {out}: the folder holds files that fpg-gym compare did not write (no "
                f"{MANIFEST_NAME}); compare writes only into a new or empty folder, or one it "
                "created: choose another --out"
            )
        if fresh:
            raise OutputError(
                f"--out {out}: --fresh deletes only files listed in {MANIFEST_NAME}, and this "
                "folder (from an earlier fpg-gym) has none; delete what you no longer need "
                "yourself, or choose another --out"
            )
        say(f"{out}: results of an earlier fpg-gym compare; resuming, and listing new files")
        legacy = True
    else:
        legacy = False
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"--out {out}: cannot create the folder ({error.strerror})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise OutputError(f"--out {out}: the folder is not writable")
    manifest = Manifest(out, adopt=legacy)
    if fresh:
        try:
            count = manifest.delete_listed()
        except BaseException:
            manifest.close()
            raise
        if count:
            say(f"--fresh: deleted {count} file(s) an earlier compare wrote in {out}")
    return manifest


def _lock_file(path: Path, out: Path) -> int | None:
    """Open ``path`` (created empty if absent) and lock it for this process; the descriptor
    (None where the platform has no ``flock``).

    Raises
    ------
    OutputError
        Another process holds the lock, or the file cannot be opened.
    """
    try:
        descriptor = os.open(path, os.O_RDWR | os.O_CREAT | os.O_APPEND, 0o644)
    except OSError as error:
        raise OutputError(f"--out {out}: cannot open {path.name} ({error.strerror})") from None
    if fcntl is None:  # pragma: no cover - not Unix
        return descriptor
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(descriptor)
        raise OutputError(
            f"--out {out}: another fpg-gym compare is writing in this folder (it holds "
            f"{path.name} locked); wait until it ends, or choose another --out"
        ) from None
    return descriptor


def _format_value(value: Any) -> Any:
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    return value


class ResultsWriter:
    """Appends rows to ``results.csv`` (header first) and flushes each one."""

    def __init__(self, path: Path) -> None:
        self.path = path
        new = not path.is_file() or path.stat().st_size == 0
        self.handle = path.open("a", newline="")
        self.writer = csv.DictWriter(
            self.handle, fieldnames=list(CSV_FIELDS), extrasaction="ignore"
        )
        if new:
            self.writer.writeheader()
            self.handle.flush()

    def write(self, row: dict[str, Any]) -> None:
        """Append ``row`` and flush it to disk.

        Raises
        ------
        OutputError
            The file cannot be written (a full disk, say), naming it.
        """
        try:
            self.writer.writerow({k: _format_value(row.get(k, "")) for k in CSV_FIELDS})
            self.handle.flush()
            os.fsync(self.handle.fileno())
        except OSError as error:
            raise OutputError(f"{self.path}: cannot write ({error.strerror})") from None

    def close(self) -> None:
        try:
            self.handle.close()
        except OSError as error:  # the last buffered bytes could not be written
            raise OutputError(f"{self.path}: cannot write ({error.strerror})") from None


def frames_path(out: Path, episode: str, method: str) -> Path:
    return out / "frames" / safe_name(episode) / f"{safe_name(method)}.npz"


def save_frames(path: Path, arrays: dict[str, np.ndarray]) -> None:
    save_npz(path, arrays)  # temporary file beside it, then renamed


def load_frames(path: Path, keys: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """The arrays of a per-frame file (only ``keys`` when given)."""
    with np.load(path, allow_pickle=False) as archive:
        return {key: archive[key] for key in archive.files if keys is None or key in keys}


#: The arrays of a per-frame file and their shapes (``T`` frames, ``S`` stages), the first
#: four always there.
_FRAME_SHAPES: dict[str, tuple[int | str, ...]] = {
    "poses": ("T", skeleton.NUM_JOINTS, 3),
    "ms": ("T",),
    "stage_names": ("S",),
    "stage_ms": ("T", "S"),
    "errors": ("T",),
    "evaluations": ("T",),
    "energy": ("T",),
    "per_joint_error": (skeleton.NUM_JOINTS,),
    "per_joint_root_error": (skeleton.NUM_JOINTS,),
    "per_joint_mpjpe": (skeleton.NUM_JOINTS,),
}
_FRAME_REQUIRED = ("poses", "ms", "stage_names", "stage_ms")


def frames_intact(path: Path) -> bool:
    """Whether a per-frame file reads whole, with the arrays and shapes compare writes (a
    damaged one is not trusted: its task runs again)."""
    try:
        check_npz(path, shapes=_FRAME_SHAPES)
        arrays = load_frames(path)
    except (FpgGymError, OSError, ValueError, EOFError, zlib.error, zipfile.BadZipFile):
        return False
    if not all(name in arrays for name in _FRAME_REQUIRED):
        return False
    numeric = [a for n, a in arrays.items() if n != "stage_names"]
    return arrays["stage_names"].dtype.kind == "U" and all(
        np.issubdtype(a.dtype, np.number) for a in numeric
    )


#: The per-frame arrays the report reads (the poses are not among them).
_REPORT_KEYS = (
    "errors",
    "per_joint_error",
    "per_joint_root_error",
    "per_joint_mpjpe",
    "ms",
    "stage_names",
    "stage_ms",
)


class FrameFiles:
    """The per-frame files of a compare folder as the report reads them: each file once."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self._loaded: dict[tuple[str, str], dict[str, np.ndarray] | None] = {}

    def get(self, episode: str, method: str) -> dict[str, np.ndarray] | None:
        """The report's arrays of one task (:data:`_REPORT_KEYS`), None without its file."""
        key = (episode, method)
        if key not in self._loaded:
            path = frames_path(self.out, episode, method)
            self._loaded[key] = (
                load_frames(path, _REPORT_KEYS) if path.is_file() and frames_intact(path) else None
            )
        return self._loaded[key]


def read_config(path: Path) -> dict[str, Any] | None:
    """The ``config.json`` of an earlier run (None when absent or unreadable: nothing in the
    folder is then trusted)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) else None
