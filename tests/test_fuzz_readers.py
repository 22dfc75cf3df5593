"""Fuzzing the readers (issues 16 and 36): whatever the bytes, a reader returns its object or
raises the project's error type (:class:`~fpg_gym.core.errors.FpgGymError`), never another
exception, and soon.

Inputs are valid files mutated (lines cut, dropped, repeated or swapped, numbers replaced by
NaN, huge or non-numbers, bytes flipped, files truncated or gzipped) and arbitrary bytes; the
``.npz`` readers also get archives of arbitrary arrays. Round 2 (issue 36) adds the definition
maps, the DeepMimic reader, the sampler model files and the training checkpoints, a compare
folder's state (manifest, config, results, per-frame files), ``@FILE`` argument lists and
whole live streams through the line parser, and checks more than the error type: what reads
is plausible (finite, a person in metres, the flags as written), and nothing of the user's is
lost (compare never deletes or changes a file it did not write, in or out of its folder).
Each test runs a bounded number of examples (a few seconds in all); ``-m slow`` runs many more.
"""

from __future__ import annotations

import gzip
import io
import json
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

from fpg_gym.core import skeleton  # noqa: E402
from fpg_gym.core.errors import DataFormatError, FpgGymError  # noqa: E402
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
        joints[:, :3] = 0.01 * np.arange(75).reshape(25, 3) + t
        joints[:, 3] = 2
        v2.append(",".join([str(333333 * t), *(f"{v:.3f}" for v in joints.ravel())]) + ",")
    files["kinect_v2"] = ("\n".join(v2) + "\n").encode()
    ntu = ["3"]
    for frame in range(3):
        ntu += ["1", "72057594037931101 0 1 1 1 1 0 0.1 0.2 2", "25"]
        ntu += [f"{0.04 * j} {0.2 + frame} 3 0 0 0 0 1 0 0 0 2" for j in range(25)]
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


# --------------------------------------------------------------------------- round 2 (issue 36)

#: Fewer examples for the tests whose every example runs a command (a compare, a training).
FEW = settings(
    max_examples=12,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    derandomize=True,
)

#: JSON values that stand for any field's content.
_JSON = st.recursive(
    st.none()
    | st.booleans()
    | st.sampled_from([0, 1, -1, 2, 0.05, 1e30, 1e308, -1e308, "false", "true", "", "x"])
    | st.text(max_size=8),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=6), children, max_size=4)
    ),
    max_leaves=12,
)


def _reads_or_refuses(reader: Callable[[], Any]) -> Any:
    """``reader()``'s result, or None when it raised the project's error (anything else fails
    the test); warnings are silenced."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return reader()
    except FpgGymError:
        return None


@pytest.fixture(scope="module")
def map_text() -> str:
    from fpg_gym.definitions import DefinitionMap

    offsets = np.zeros((20, 3))
    offsets[skeleton.joint_index("Head")] = [0.0, -0.02, 0.05]
    offsets[skeleton.joint_index("HipLeft")] = [0.03, 0.01, 0.0]
    return json.dumps(DefinitionMap(offsets, "kinect-v2", "vicon").to_dict(), indent=1)


@FAST
@given(data=st.data())
def test_definition_maps_read_as_written_or_are_refused(
    map_text: str, tmp_path: Path, data: Any
) -> None:
    from fpg_gym.definitions import DefinitionMap

    document = json.loads(map_text)
    if data.draw(st.booleans()):  # a field replaced by any JSON value
        field = data.draw(st.sampled_from([*document, "offsets_m.Head", "offsets_m.Spine"]))
        value = data.draw(_JSON)
        if field.startswith("offsets_m."):
            document["offsets_m"][field.split(".", 1)[1]] = value
        else:
            document[field] = value
        raw = json.dumps(document).encode()
    else:  # the text mutated
        raw = data.draw(_mutated_text(map_text.encode()))
    path = tmp_path / "map.json"
    path.write_bytes(raw)
    loaded = _reads_or_refuses(lambda: DefinitionMap.load(path))
    if loaded is None:
        return
    # What reads is what the file says: a JSON boolean, finite offsets under 0.5 m, and a map
    # that moves a real pose by no more than its offsets.
    written = json.loads(raw.decode("utf-8-sig"))
    assert loaded.inverted is written.get("inverted", False)
    assert isinstance(loaded.inverted, bool)
    assert np.all(np.isfinite(loaded.offsets)) and np.abs(loaded.offsets).max() <= 0.5
    pose = load_default_clips(["walk"])[0].positions[:2]
    moved = loaded.apply(pose)
    assert np.all(np.isfinite(moved))
    assert (
        np.linalg.norm(moved - pose, axis=-1).max()
        <= 1.01 * np.linalg.norm(loaded.offsets, axis=-1).max() + 1e-6
    )


@pytest.fixture(scope="module")
def deepmimic_text() -> bytes:
    from fpg_gym.io.deepmimic import default_clip_path

    document = json.loads(default_clip_path("walk").read_text())
    document["Frames"] = document["Frames"][:8]
    lines = ["{", '"Loop": "wrap",', '"Frames":', "["]
    lines += [json.dumps(frame) + ("," if i < 7 else "") for i, frame in enumerate(
        document["Frames"])]  # fmt: skip
    lines += ["]", "}"]
    return "\n".join(lines).encode()


@FAST
@given(data=st.data())
def test_the_deepmimic_reader_gives_a_plausible_clip_or_refuses(
    deepmimic_text: bytes, tmp_path: Path, data: Any
) -> None:
    from fpg_gym.io import read_deepmimic
    from fpg_gym.io.plausibility import BODY_SIZE_M, MAX_COORDINATE_M, body_size

    path = tmp_path / "humanoid3d_fuzz.txt"
    path.write_bytes(data.draw(_mutated_text(deepmimic_text)))
    start = time.perf_counter()
    clip = _reads_or_refuses(lambda: read_deepmimic(path))
    assert time.perf_counter() - start < SLOW_READ_S
    if clip is None:
        return
    assert clip.fps == 30.0 and clip.num_frames >= 1
    assert np.all(np.isfinite(clip.positions))
    assert np.abs(clip.positions).max() <= MAX_COORDINATE_M
    size = body_size(clip.positions)
    assert size is None or BODY_SIZE_M[0] <= size <= BODY_SIZE_M[1]


@pytest.fixture(scope="module")
def linear_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    """A linear sampler's files (made-up arrays of the right shapes), as bytes."""
    from policies.pose_sampler import LINEAR_FEATURES, LinearPoseSampler
    from policies.sampler import SamplerSpec

    spec = SamplerSpec.for_layout(
        "linear", "ridge", 4, 5, action_mode="absolute", features=list(LINEAR_FEATURES)
    )
    folder = tmp_path_factory.mktemp("linear")
    probe = folder / "probe"
    sampler = LinearPoseSampler(
        spec,
        {
            "regressor_mean": np.zeros(1),
            "regressor_scale": np.ones(1),
            "weights": np.zeros((1, 60)),
            "bias": np.zeros(60),
            "std": np.ones(4),
        },
    )
    try:  # the regressor count follows the features: take it from the loader's refusal
        sampler.save(probe)
        from policies.loading import load_sampler

        load_sampler(probe)
        size = 1
    except DataFormatError as error:
        size = int(str(error).split("shape (")[1].split(",")[0])
    arrays = {
        "regressor_mean": np.zeros(size),
        "regressor_scale": np.ones(size),
        "weights": np.full((size, 60), 0.01),
        "bias": np.zeros(60),
        "std": np.full(4, 0.5),
    }
    path = LinearPoseSampler(spec, arrays).save(folder / "model")
    return {"json": path.read_bytes(), "npz": path.with_suffix(".npz").read_bytes()}


@FAST
@given(data=st.data())
def test_sampler_model_files_load_sane_or_are_refused(
    linear_files: dict[str, bytes], tmp_path: Path, data: Any
) -> None:
    from policies.loading import load_sampler
    from policies.sampler import MAX_MODEL_VALUE

    json_bytes, npz_bytes = linear_files["json"], linear_files["npz"]
    target = data.draw(st.sampled_from(["json-text", "json-field", "npz-bytes", "npz-arrays"]))
    if target == "json-text":
        json_bytes = data.draw(_mutated_text(json_bytes))
    elif target == "json-field":
        document = json.loads(json_bytes)
        field = data.draw(st.sampled_from([*document, "hyperparameters.penalty"]))
        if "." in field:
            document["hyperparameters"]["penalty"] = data.draw(_JSON)
        else:
            document[field] = data.draw(_JSON)
        json_bytes = json.dumps(document).encode()
    elif target == "npz-bytes":
        npz_bytes = data.draw(_mutated_bytes(npz_bytes))
    else:
        with np.load(io.BytesIO(npz_bytes)) as archive:
            arrays = {k: archive[k] for k in archive.files}
        name = data.draw(st.sampled_from(sorted(arrays)))
        value = data.draw(st.sampled_from([np.nan, np.inf, -1.0, 1e300, 1e7, 0.0]))
        arrays[name] = arrays[name].copy()
        arrays[name].flat[data.draw(st.integers(0, arrays[name].size - 1))] = value
        buffer = io.BytesIO()
        np.savez(buffer, **arrays)
        npz_bytes = buffer.getvalue()
    (tmp_path / "model.json").write_bytes(json_bytes)
    (tmp_path / "model.npz").write_bytes(npz_bytes)
    sampler = _reads_or_refuses(lambda: load_sampler(tmp_path / "model"))
    if sampler is None:
        return
    for name, values in sampler.arrays.items():  # a loaded model is a sane one
        assert np.all(np.isfinite(values)) and np.abs(values).max() <= MAX_MODEL_VALUE, name
    assert np.all(sampler.arrays["std"] >= 0) and np.all(sampler.arrays["regressor_scale"] > 0)
    assert 0 < sampler.spec.action_scale <= 1e3


@FAST
@given(data=st.data())
def test_training_checkpoints_resume_or_are_refused(tmp_path: Path, data: Any) -> None:
    from policies.checkpoints import RUN_FORMAT, RunCheckpoints, settings_digest

    folder = tmp_path / "m.checkpoints"
    folder.mkdir(exist_ok=True)
    for old in folder.iterdir():
        old.unlink()
    settings = {"kind": "linear", "seed": 0, "clips": ["run", "jump"]}
    run = {"format": RUN_FORMAT, "digest": settings_digest(settings), "settings": settings}
    text = json.dumps(run).encode()
    which = data.draw(st.sampled_from(["run-text", "run-field", "data"]))
    if which == "run-text":
        text = data.draw(_mutated_text(text))
    elif which == "run-field":
        run[data.draw(st.sampled_from(["format", "digest", "settings"]))] = data.draw(_JSON)
        text = json.dumps(run).encode()
    (folder / "run.json").write_bytes(text)
    if which == "data":
        arrays = data.draw(_arrays())
        np.savez(folder / "data-00000-00007.npz", **arrays)
    user_file = folder / "notes.txt"
    user_file.write_text("mine")
    checkpoints = _reads_or_refuses(lambda: RunCheckpoints(folder, settings))
    if checkpoints is not None:
        done = _reads_or_refuses(checkpoints.collected_episodes)
        assert done is None or all(isinstance(e, int) for e in done)
    RunCheckpoints(folder, settings, restart=True)  # --restart always starts over ...
    assert user_file.read_text() == "mine"  # ... and removes only its own files


def test_training_checkpoints_of_other_settings_name_them(tmp_path: Path) -> None:
    from fpg_gym.core.errors import OutputError
    from policies.checkpoints import RunCheckpoints

    RunCheckpoints(tmp_path / "c", {"seed": 0, "clips_sha256": ["a"]})
    with pytest.raises(OutputError, match=r"clips_sha256 differ.*--restart"):
        RunCheckpoints(tmp_path / "c", {"seed": 0, "clips_sha256": ["b"]})


@pytest.fixture(scope="module")
def compare_template(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A finished compare folder (raw and holt on one recording) and its input."""
    from fpg_gym.experiments import CompareConfig, run_compare
    from fpg_gym.simulate import simulate

    root = tmp_path_factory.mktemp("compare")
    take = simulate(load_default_clips(["punch"])[0], "front-many", seed=0).head(10)
    source = write_recording(root / "take.npz", take)
    config = CompareConfig(out=str(root / "run"), methods=["raw", "holt"], inputs=[str(source)])
    run_compare(config, progress=False, plots=False, log=lambda _: None)
    return root / "run", source


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@FEW
@given(data=st.data())
def test_compare_state_resumes_or_refuses_and_never_loses_the_users_files(
    compare_template: tuple[Path, Path], tmp_path: Path, data: Any
) -> None:
    import shutil

    from fpg_gym.experiments import CompareConfig, run_compare
    from fpg_gym.experiments.store import MANIFEST_NAME

    template, source = compare_template
    work = tmp_path / f"w{time.perf_counter_ns()}"
    out = work / "run"
    shutil.copytree(template, out)
    outside = work / "outside.txt"
    outside.write_text("not compare's")
    (work / "elsewhere").mkdir()
    (work / "elsewhere" / "data.txt").write_text("not compare's either")
    (out / "frames" / "link").symlink_to(work / "elsewhere")
    (out / "notes.md").write_text("mine")
    which = data.draw(st.sampled_from(["manifest", "config", "results", "frames", "episode"]))
    if which == "manifest":
        hostile = ["../outside.txt", str(outside), "frames/link", "frames/link/data.txt", "", "#"]
        hostile += ["..", "/", "notes.md/..", "frames"]
        extra = data.draw(st.lists(st.sampled_from(hostile), max_size=4))
        text = (out / MANIFEST_NAME).read_bytes()
        text = data.draw(_mutated_text(text + "".join(f"{e}\n" for e in extra).encode()))
        (out / MANIFEST_NAME).write_bytes(text)
    elif which == "config":
        text = (out / "config.json").read_bytes()
        if data.draw(st.booleans()):
            text = data.draw(_mutated_text(text))
        else:
            document = json.loads(text)
            document[data.draw(st.sampled_from(sorted(document)))] = data.draw(_JSON)
            text = json.dumps(document).encode()
        (out / "config.json").write_bytes(text)
    elif which == "results":
        path = out / "results.csv"
        path.write_bytes(data.draw(_mutated_text(path.read_bytes())))
    else:
        pattern = "frames/*/*.npz" if which == "frames" else "episodes/*.npz"
        target = sorted(out.glob(pattern))[0]
        if data.draw(st.booleans()):
            target.write_bytes(data.draw(_mutated_bytes(target.read_bytes())))
        else:
            buffer = io.BytesIO()
            np.savez(buffer, **data.draw(_arrays()))
            target.write_bytes(buffer.getvalue())
    user_files = {"notes.md": b"mine"}
    fresh = data.draw(st.booleans())
    config = CompareConfig(out=str(out), methods=["raw", "holt"], inputs=[str(source)])
    start = time.perf_counter()
    outcome = _reads_or_refuses(
        lambda: run_compare(config, progress=False, plots=False, fresh=fresh, log=lambda _: None)
    )
    assert time.perf_counter() - start < 60
    # Nothing of the user's is lost, whatever the state said.
    assert outside.read_text() == "not compare's"
    assert (work / "elsewhere" / "data.txt").read_text() == "not compare's either"
    for name, content in user_files.items():
        if not fresh or name not in (out / MANIFEST_NAME).read_text(errors="replace"):
            assert (out / name).read_bytes() == content
    if outcome is None:
        return
    # A finished run is a consistent one: each task once, with its per-frame file.
    import csv

    rows = list(csv.DictReader((out / "results.csv").open(newline="")))
    keys = [(r["episode"], r["method"]) for r in rows]
    assert sorted(set(keys)) == sorted(keys) and len(keys) == 2
    for episode, method in keys:
        assert (out / "frames" / episode / f"{method}.npz").is_file()
    assert outcome.summary["method_order"] == ["raw", "holt"]


@FAST
@given(raw=st.binary(max_size=300) | st.text(max_size=200).map(lambda t: t.encode()))
def test_argument_files_expand_to_arguments_never_options(tmp_path: Path, raw: bytes) -> None:
    from fpg_gym.cli import CommandLineError, expand_argument_files

    listing = tmp_path / "args.txt"
    listing.write_bytes(raw)
    before = ["compare", "--out", "x", "-v"]
    expanded = _reads_or_refuses(lambda: expand_argument_files([*before, f"@{listing}"]))
    if expanded is None:
        with pytest.raises(CommandLineError, match=r"args\.txt"):
            expand_argument_files([f"@{listing}"])
        return
    assert expanded[: len(before)] == before  # arguments outside the file untouched
    from_file = expanded[len(before) :]
    assert all(item and not item.startswith("-") and item == item.strip() for item in from_file)
    assert len(from_file) == sum(1 for line in raw.decode().splitlines() if line.strip())


@st.composite
def _live_stream(draw: Any) -> list[str]:
    """A sender's lines: frames with timestamps that run on, jump, restart or go missing,
    between malformed lines and the end marker."""
    from fpg_gym.io.live_frames import frame_line

    pose = load_default_clips(["walk"])[0].positions[0]
    lines: list[str] = []
    stamp = draw(st.sampled_from([0.0, 1e9, -5.0]))
    for _ in range(draw(st.integers(1, 12))):
        kind = draw(st.sampled_from(["frame", "frame", "jump", "restart", "bare", "junk", "end"]))
        if kind == "junk":
            lines.append(draw(st.sampled_from(['{"joints": 1}', "{", '{"joints": []}', "null",
                '{"end": "yes"}', '{"timestamp": 1e999, "joints": 0}', "[" * 50])))  # fmt: skip
            continue
        if kind == "end":
            lines.append('{"end": true}')
            continue
        stamp = {"frame": stamp + 1 / 30, "jump": stamp + draw(st.sampled_from([3600.0, -1e6])),
                 "restart": 0.0, "bare": stamp}[kind]  # fmt: skip
        moved = pose + draw(st.sampled_from([0.0, 0.01, 999.0, 1001.0]))
        states = draw(st.sampled_from([None, [2] * 20, [3] * 20]))
        line = frame_line(moved, states, None if kind == "bare" else stamp)
        lines.append(line if draw(st.integers(0, 4)) else line[: draw(st.integers(0, len(line)))])
    return lines


@FAST
@given(lines=_live_stream())
def test_whole_live_streams_parse_frame_by_frame(lines: list[str]) -> None:
    from fpg_gym.io.live_frames import FrameError, is_end, parse_frame
    from fpg_gym.io.plausibility import MAX_COORDINATE_M

    parsed = 0
    for line in lines:
        ended = is_end(line)
        assert isinstance(ended, bool)
        if ended:
            continue
        try:
            frame = parse_frame(line, index=parsed)
        except FrameError as error:
            assert error.reason and "\n" not in str(error)
            continue
        parsed += 1
        assert frame.positions.shape == (20, 3) and frame.positions.dtype == np.float32
        assert np.all(np.isfinite(frame.positions))
        assert np.abs(frame.positions).max() <= MAX_COORDINATE_M
        assert set(frame.states.tolist()) <= {0, 1, 2}
        assert frame.timestamp is None or np.isfinite(frame.timestamp)
