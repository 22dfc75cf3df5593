"""Fuzzing the readers (issue 16): whatever the bytes, a reader returns its object or raises the
project's error type (:class:`~fpg_gym.errors.FpgGymError`), never another exception, and soon.

Inputs are valid files mutated (lines cut, dropped, repeated or swapped, numbers replaced by
NaN, huge or non-numbers, bytes flipped, files truncated or gzipped) and arbitrary bytes; the
``.npz`` readers also get archives of arbitrary arrays. Each test runs a bounded number of
examples (a few seconds in all); ``-m slow`` runs many more.
"""

from __future__ import annotations

import gzip
import io
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import tiny_bvh

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from fpg_gym import skeleton  # noqa: E402
from fpg_gym.errors import FpgGymError  # noqa: E402
from fpg_gym.graph import FilteredPoseGraph  # noqa: E402
from fpg_gym.io import load_default_clips, read_bvh, read_positions, write_positions  # noqa: E402
from fpg_gym.io.kinect import (  # noqa: E402
    read_csv,
    read_kinect_v2,
    read_msrc12,
    read_ntu,
    read_recording,
    write_csv,
)
from fpg_gym.io.recording import load_recording, write_recording  # noqa: E402

#: Examples per test by default, and with ``-m slow``.
FAST = settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    derandomize=True,
)
#: Seconds one read may take on these small files before it counts as a hang.
SLOW_READ_S = 5.0

_BVH = tiny_bvh(
    [
        "0 100 0 0 0 0 0 0 0 0 0 0",
        "10 100 0 0 0 90 90 90 0 0 0 0",
        "20 100 0 5 0 90 90 45 0 0 1 0",
        "30 100 0 5 0 90 90 45 0 0 1 0",
    ]
)
_ANY_MAP = {name: "Hips" for name in skeleton.JOINT_NAMES}
_TOKENS = ["nan", "NaN", "inf", "-inf", "1e30", "3.5e38", "1e400", "-", "x", ",", "", "0", "1e9"]


def _seed_files(root: Path) -> dict[str, bytes]:
    """Valid files of every format (small)."""
    from fpg_gym.simulate import simulate

    clip = load_default_clips(["punch"])[0]
    recording = simulate(clip, "front-many", seed=0).head(6)
    files: dict[str, bytes] = {"bvh": _BVH.encode()}
    csv_path = write_csv(root / "seed.csv", recording)
    files["csv"] = csv_path.read_bytes()
    to_v1 = np.argsort(skeleton.FROM_KINECT_V1)
    v1 = []
    for t, frame in enumerate(recording.positions[:, to_v1]):
        values = np.concatenate([frame, np.ones((20, 1))], axis=1).ravel()
        v1.append(" ".join([str(33 * t), *(f"{v:.3f}" for v in values)]))
    files["msrc12"] = ("\n".join(v1) + "\n").encode()
    v2 = []
    for t in range(len(recording.positions)):
        joints = np.zeros((25, 4))
        joints[:, :3] = 0.1 * np.arange(75).reshape(25, 3) + t
        joints[:, 3] = 2
        v2.append(",".join([str(333333 * t), *(f"{v:.3f}" for v in joints.ravel())]) + ",")
    files["kinect_v2"] = ("\n".join(v2) + "\n").encode()
    ntu = ["3"]
    for frame in range(3):
        ntu += ["1", "72057594037931101 0 1 1 1 1 0 0.1 0.2 2", "25"]
        ntu += [f"{0.1 * j} {0.2 + frame} 3 0 0 0 0 1 0 0 0 2" for j in range(25)]
    files["ntu"] = ("\n".join(ntu) + "\n").encode()
    files["recording"] = write_recording(root / "seed.npz", recording).read_bytes()
    files["positions"] = write_positions(root / "pos.npz", clip).read_bytes()
    return files


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    return _seed_files(tmp_path_factory.mktemp("fuzz-seeds"))


@pytest.fixture(scope="module")
def graph_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    clips = load_default_clips(["punch", "kick"])
    graph = FilteredPoseGraph.build(clips, thres1=0.3, progress=False)
    return graph.save(tmp_path_factory.mktemp("fuzz-graph") / "g.npz").read_bytes()


@st.composite
def _mutated_text(draw: Any, text: bytes) -> bytes:
    """``text`` with a few line- and token-level mutations, maybe truncated or gzipped."""
    lines = text.decode().split("\n")
    for _ in range(draw(st.integers(1, 4))):
        if not lines:
            break
        index = draw(st.integers(0, len(lines) - 1))
        action = draw(st.sampled_from(["cut", "drop", "repeat", "token", "swap", "junk"]))
        if action == "cut":
            lines[index] = lines[index][: draw(st.integers(0, max(len(lines[index]), 1)))]
        elif action == "drop":
            del lines[index]
        elif action == "repeat":
            lines.insert(index, lines[index])
        elif action == "swap" and len(lines) > 1:
            other = draw(st.integers(0, len(lines) - 1))
            lines[index], lines[other] = lines[other], lines[index]
        elif action == "token":
            separator = "," if lines[index].count(",") > 2 else " "
            fields = lines[index].split(separator)
            if fields:
                position = draw(st.integers(0, len(fields) - 1))
                fields[position] = draw(st.sampled_from(_TOKENS))
                lines[index] = separator.join(fields)
        else:
            lines.insert(index, draw(st.text(max_size=40)))
    data = "\n".join(lines).encode("utf-8", errors="replace")
    if draw(st.booleans()):
        data = data[: draw(st.integers(0, len(data)))]
    if draw(st.integers(0, 5)) == 0:
        data = gzip.compress(data)
        if draw(st.booleans()):
            data = data[: draw(st.integers(0, len(data)))]
    return data


@st.composite
def _mutated_bytes(draw: Any, data: bytes) -> bytes:
    """``data`` with bytes flipped, a piece cut out, or truncated (binary formats)."""
    buffer = bytearray(data)
    for _ in range(draw(st.integers(1, 3))):
        if not buffer:
            break
        action = draw(st.sampled_from(["flip", "truncate", "splice"]))
        position = draw(st.integers(0, len(buffer) - 1))
        if action == "flip":
            buffer[position] ^= draw(st.integers(1, 255))
        elif action == "truncate":
            del buffer[position:]
        else:
            del buffer[position : position + draw(st.integers(1, 64))]
    return bytes(buffer)


def _check(reader: Callable[[Path], Any], path: Path, data: bytes) -> None:
    """``reader(path)`` on ``data``: returns, or raises the project's error; never anything
    else, never slowly."""
    path.write_bytes(data)
    start = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader(path)
    except FpgGymError:
        pass
    elapsed = time.perf_counter() - start
    assert elapsed < SLOW_READ_S, f"{reader.__name__} took {elapsed:.1f} s on {len(data)} bytes"


_TEXT_READERS: dict[str, tuple[str, Callable[[Path], Any]]] = {
    "bvh": ("x.bvh", lambda p: read_bvh(p, _ANY_MAP)),
    "msrc12": ("x.txt", read_msrc12),
    "kinect_v2": ("x.txt", read_kinect_v2),
    "ntu": ("x.skeleton", read_ntu),
    "csv": ("x.csv", read_csv),
}


@pytest.mark.parametrize("fmt", list(_TEXT_READERS))
@FAST
@given(data=st.data())
def test_text_readers_read_or_raise_the_project_error(
    fmt: str, seeds: dict[str, bytes], tmp_path: Path, data: Any
) -> None:
    name, reader = _TEXT_READERS[fmt]
    mutated = data.draw(_mutated_text(seeds[fmt]))
    _check(reader, tmp_path / name, mutated)
    if fmt != "bvh":  # and through the format guess
        _check(read_recording, tmp_path / f"auto-{name}", mutated)


@FAST
@given(raw=st.binary(max_size=600))
def test_readers_survive_arbitrary_bytes(tmp_path: Path, raw: bytes) -> None:
    for name, reader in [
        ("x.bvh", lambda p: read_bvh(p, _ANY_MAP)),
        ("x.txt", read_recording),
        ("x.skeleton", read_recording),
        ("x.npz", read_recording),
        ("y.npz", read_positions),
        ("z.npz", FilteredPoseGraph.load),
    ]:
        _check(reader, tmp_path / name, raw)


@pytest.mark.parametrize("fmt", ["recording", "positions", "graph"])
@FAST
@given(data=st.data())
def test_npz_readers_survive_corrupt_archives(
    fmt: str, seeds: dict[str, bytes], graph_bytes: bytes, tmp_path: Path, data: Any
) -> None:
    source = graph_bytes if fmt == "graph" else seeds[fmt]
    reader = {
        "recording": load_recording,
        "positions": read_positions,
        "graph": FilteredPoseGraph.load,
    }[fmt]
    _check(reader, tmp_path / "x.npz", data.draw(_mutated_bytes(source)))


_DTYPES = st.sampled_from(["<f4", "<f8", "<i1", "<i8", "|b1", "<U8", "|S4", "<c8", "<M8[s]"])


@st.composite
def _arrays(draw: Any) -> dict[str, np.ndarray]:
    """Archives of arbitrary small arrays under the readers' key names (and others)."""
    keys = draw(
        st.lists(
            st.sampled_from(
                [
                    "positions",
                    "states",
                    "timestamps",
                    "ground_truth",
                    "metadata",
                    "fps",
                    "name",
                    "poses",
                    "clip_index",
                    "frame_index",
                    "mirrored",
                    "indptr",
                    "indices",
                    "clip_names",
                    "other",
                ]
            ),
            unique=True,
            max_size=10,
        )
    )
    arrays: dict[str, np.ndarray] = {}
    for key in keys:
        shape = tuple(draw(st.lists(st.sampled_from([0, 1, 2, 3, 20]), max_size=3)))
        dtype = np.dtype(draw(_DTYPES))
        size = int(np.prod(shape, dtype=np.int64))
        if dtype.kind in "US":
            values = np.array(
                [draw(st.sampled_from(["{}", "[]", '{"format_version": 1}', "x", "nan"]))] * size,
                dtype=dtype,
            )
        elif dtype.kind == "M":
            values = np.zeros(size, dtype=dtype)
        else:
            values = np.array(
                draw(
                    st.lists(
                        st.sampled_from([0, 1, 2, -1, 1e39, float("nan"), 1e9]),
                        min_size=size,
                        max_size=size,
                    )
                )
            )
            with np.errstate(all="ignore"):
                values = values.astype(dtype) if dtype.kind != "b" else values.astype(bool)
        arrays[key] = values.reshape(shape)
    return arrays


@FAST
@given(arrays=_arrays())
def test_npz_readers_survive_arbitrary_arrays(tmp_path: Path, arrays: dict[str, Any]) -> None:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    raw = buffer.getvalue()
    for reader in (load_recording, read_positions, FilteredPoseGraph.load, read_recording):
        _check(reader, tmp_path / "x.npz", raw)


@pytest.mark.slow
@pytest.mark.parametrize("fmt", list(_TEXT_READERS))
@settings(max_examples=1000, deadline=None, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_text_readers_long_fuzz(
    fmt: str, seeds: dict[str, bytes], tmp_path: Path, data: Any
) -> None:
    name, reader = _TEXT_READERS[fmt]
    mutated = data.draw(_mutated_text(seeds[fmt]))
    _check(reader, tmp_path / name, mutated)
    if fmt != "bvh":
        _check(read_recording, tmp_path / f"auto-{name}", mutated)


def test_the_seed_files_are_valid(seeds: dict[str, bytes], tmp_path: Path) -> None:
    """The fuzzed files start valid: each reader reads its seed."""
    for fmt, (name, reader) in _TEXT_READERS.items():
        path = tmp_path / name
        path.write_bytes(seeds[fmt])
        reader(path)
    (tmp_path / "r.npz").write_bytes(seeds["recording"])
    assert load_recording(tmp_path / "r.npz").num_frames == 6
    (tmp_path / "p.npz").write_bytes(seeds["positions"])
    read_positions(tmp_path / "p.npz")
    assert os.path.getsize(tmp_path / "p.npz") > 0
