"""A supervised training run's resumable files: the imitation data by chunk, the fit's state.

``fpg-gym train-sampler --kind supervised --out MODEL`` writes into ``MODEL.checkpoints/``, as it
goes:

* ``run.json``: the run's settings (those that decide the data and the weights) and their
  digest;
* ``data-EEEEE-FFFFF.npz``: the (observation, target) pairs of episodes ``E`` to ``F``, one file
  per finished chunk of episodes (compressed ``.npz``, read with ``allow_pickle=False``);
* ``fit.json`` and ``fit.pt``: the fit after its last finished epoch
  (:class:`~policies.supervised_fit.FitState`: network, Adam, the shuffling generator, the best
  epoch so far and the epoch records);
* ``epoch-NNNN.json`` / ``.pt``: the sampler at each periodic evaluation (as before).

Every file is written to a temporary name and renamed, so a run stopped at any point (Ctrl-C,
kill, a crash) leaves only whole files; a run that ends with its model written removes them
(:meth:`RunCheckpoints.finish`). Running the same command again goes on from them:
the episodes already collected are read back, the others collected (each episode has its own
generator, so the pairs are the same as an uninterrupted run's) and the fit goes on from its
last epoch (the same weights, tested). A run with other settings refuses the folder unless
told to start over (``--restart``), which removes these files (and only these).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import zipfile
import zlib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fpg_gym.core.errors import DataFormatError, OutputError
from fpg_gym.core.jsonable import jsonable
from fpg_gym.core.outputs import atomic_path, save_npz
from fpg_gym.io.files import read_json
from fpg_gym.io.npz import check_npz
from policies.imitation import ImitationData
from policies.supervised_fit import FitState

__all__ = ["RunCheckpoints", "settings_digest"]

#: ``format`` of ``run.json``.
RUN_FORMAT = "fpg-gym-training-run"
_DATA_NAME = re.compile(r"^data-(\d{5,})-(\d{5,})\.npz$")
_FIT_STEM = "fit"
_DATA_FIELDS = ("observations", "actions", "masks", "episodes", "search_energies")
#: Shapes of a data file's arrays: ``N`` pairs of ``W`` observation values and ``L`` actions.
_DATA_SHAPES: dict[str, tuple[int | str, ...]] = {
    "chunk": ("E",),
    "observations": ("N", "W"),
    "actions": ("N", "L"),
    "masks": ("N", "L"),
    "episodes": ("N",),
    "search_energies": ("N",),
}


def settings_digest(settings: Mapping[str, Any]) -> str:
    """SHA-256 of the settings' canonical JSON (sorted keys)."""
    text = json.dumps(jsonable(settings), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class RunCheckpoints:
    """The checkpoint folder of one training run (see the module docstring).

    Parameters
    ----------
    folder : path
        ``MODEL.checkpoints``.
    settings : mapping
        The settings that decide the data and the weights (JSON values).
    restart : bool
        Start over: remove this module's files from ``folder`` first.
    log : callable, optional
        Receives a line when the run starts over.

    Raises
    ------
    OutputError
        When ``folder`` holds a run with other settings and ``restart`` is False (naming the
        settings that differ).
    DataFormatError
        When ``run.json`` is not a run description.
    """

    def __init__(
        self,
        folder: str | os.PathLike[str],
        settings: Mapping[str, Any],
        *,
        restart: bool = False,
        log: Callable[[str], None] | None = None,
    ) -> None:
        self.folder = Path(folder)
        self.settings = jsonable(dict(settings))
        self.digest = settings_digest(self.settings)
        say = log or (lambda _text: None)
        earlier = None if restart else self._read_run()  # --restart: even a damaged run.json
        if restart:
            removed = self._remove_own_files()
            if removed:
                say(f"{self.folder}: started over ({removed} checkpoint files removed)")
        elif earlier is not None and earlier.get("digest") != self.digest:
            old = earlier.get("settings", {})
            changed = sorted(
                key
                for key in set(old) | set(self.settings)
                if old.get(key) != self.settings.get(key)
            )
            raise OutputError(
                f"{self.folder}: checkpoints of a run with other settings ({', '.join(changed)}"
                " differ); give the same settings to go on, or --restart to start over "
                "(removes its data and fit checkpoints)"
            )
        self.folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.folder / "run.json") as temporary:
            description = {"format": RUN_FORMAT, "digest": self.digest, "settings": self.settings}
            temporary.write_text(json.dumps(description, indent=1) + "\n")

    # ------------------------------------------------------------------ files

    def _read_run(self) -> dict[str, Any] | None:
        path = self.folder / "run.json"
        if not path.exists() and not path.is_symlink():
            return None
        data = read_json(path)
        if not isinstance(data, dict) or data.get("format") != RUN_FORMAT:
            raise DataFormatError(path, f"expected format {RUN_FORMAT!r}", field="format")
        if not isinstance(data.get("settings", {}), dict):
            raise DataFormatError(path, "expected a JSON object of settings", field="settings")
        if not isinstance(data.get("digest", ""), str):
            raise DataFormatError(path, "expected a SHA-256 digest", field="digest")
        return data

    def _data_files(self) -> list[tuple[int, int, Path]]:
        """``(first, last, path)`` of the data files, by first episode."""
        if not self.folder.is_dir():
            return []
        found = []
        for path in self.folder.iterdir():
            match = _DATA_NAME.match(path.name)
            if match:
                found.append((int(match[1]), int(match[2]), path))
        return sorted(found)

    def _remove_own_files(self) -> int:
        """Remove the data files, the fit state and ``run.json`` (nothing else); their number."""
        own = [path for _, _, path in self._data_files()]
        own += [self.folder / f"{_FIT_STEM}{suffix}" for suffix in (".json", ".pt")]
        own.append(self.folder / "run.json")
        removed = 0
        for path in own:
            if path.is_file():
                path.unlink()
                removed += 1
        return removed

    # ------------------------------------------------------------------ data

    def collected_episodes(self) -> set[int]:
        """Episodes whose pairs are on disk."""
        done: set[int] = set()
        for first, last, path in self._data_files():
            done.update(int(e) for e in self._read(path, ("chunk",))["chunk"])
            if not done >= {first, last}:
                raise DataFormatError(path, "the episodes of its name are not in its 'chunk'")
        return done

    @staticmethod
    def _read(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
        """Arrays of a data file, checked before they are inflated (sizes within the memory
        ceiling, one row count across them; no pickle); a damaged file is named."""
        check_npz(path, names, shapes=_DATA_SHAPES)
        try:
            with np.load(path, allow_pickle=False) as archive:
                arrays = {name: np.asarray(archive[name]) for name in names}
        except (OSError, ValueError, KeyError, EOFError, zlib.error, zipfile.BadZipFile) as error:
            raise DataFormatError(
                path, f"not a training-data checkpoint ({error}); --restart starts over"
            ) from None
        for name, array in arrays.items():
            if not np.issubdtype(array.dtype, np.number) and array.dtype != bool:
                raise DataFormatError(path, f"expected numbers, got {array.dtype}", field=name)
        return arrays

    def save_chunk(self, episodes: Sequence[int], data: ImitationData) -> Path:
        """Write the pairs of one finished chunk of ``episodes`` (ascending)."""
        chunk = np.asarray(episodes, dtype=np.int64)
        path = self.folder / f"data-{int(chunk[0]):05d}-{int(chunk[-1]):05d}.npz"
        arrays = {name: getattr(data, name) for name in _DATA_FIELDS}
        return save_npz(path, {"chunk": chunk, **arrays}, compressed=True)

    def merged_data(self, new: ImitationData) -> ImitationData:
        """``new`` (the pairs collected by this run, saved or not) and the pairs on disk of the
        other episodes, in episode order."""
        fresh = set(np.unique(new.episodes).tolist())
        parts = []
        for _, _, path in self._data_files():
            arrays = self._read(path, ("chunk", *_DATA_FIELDS))
            if fresh.isdisjoint(arrays["chunk"].tolist()):
                try:
                    parts.append(ImitationData(*(arrays[f] for f in _DATA_FIELDS)))
                except (TypeError, ValueError) as error:
                    raise DataFormatError(path, f"inconsistent arrays ({error})") from None
        if not parts:
            return new
        # Each episode's rows are contiguous and in frame order: a stable sort by episode gives
        # the uninterrupted run's order.
        merged = ImitationData.concatenate([*parts, new])
        order = np.argsort(merged.episodes, kind="stable")
        return ImitationData(*(getattr(merged, f)[order] for f in _DATA_FIELDS))

    # ------------------------------------------------------------------ fit

    def load_fit(self) -> FitState | None:
        """The fit state on disk, or None."""
        stem = self.folder / _FIT_STEM
        if not stem.with_suffix(".json").is_file():
            return None
        return FitState.load(stem)

    def save_fit(self, state: FitState) -> None:
        """Write the fit's state (replacing the previous one)."""
        state.save(self.folder / _FIT_STEM)

    def finish(self) -> int:
        """The run is over and its model written: remove the data, the fit's state and
        ``run.json`` (the default run's 20,000 observations of 2,304 float32 values are 184 MB
        before compression); the number of files removed.
        The periodic samplers (``epoch-NNNN``) stay."""
        return self._remove_own_files()
