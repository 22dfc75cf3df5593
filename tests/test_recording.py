"""The Recording type and its .npz format."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fpg_gym.core import poses
from fpg_gym.core.errors import DataFormatError
from fpg_gym.io import Recording, read_recording, write_recording
from fpg_gym.io.recording import RECORDING_KEYS, load_recording


def make_recording(rng: np.random.Generator, frames: int = 12, truth: bool = True) -> Recording:
    clean = poses.rest_pose()[None] + rng.normal(scale=0.01, size=(frames, 20, 3))
    states = rng.integers(0, 3, size=(frames, 20))
    return Recording(
        positions=clean + rng.normal(scale=0.02, size=clean.shape),
        states=states,
        timestamps=np.arange(frames) / 30.0,
        ground_truth=clean if truth else None,
        metadata={"source": "test", "untracked_positions": "sensor", "nested": {"a": [1, 2]}},
    )


@pytest.mark.parametrize("truth", [True, False])
def test_round_trip_keeps_everything(tmp_path: Path, rng: np.random.Generator, truth: bool) -> None:
    recording = make_recording(rng, truth=truth)
    path = write_recording(tmp_path / "rec.npz", recording)
    with np.load(path, allow_pickle=False) as archive:
        expected = set(RECORDING_KEYS) - {"occluded"}
        expected = expected if truth else expected - {"ground_truth"}
        assert set(archive.files) == expected
        assert archive["positions"].dtype == np.float32
        assert archive["positions"].shape == (12, 20, 3)
        assert archive["states"].dtype == np.int8
        assert archive["timestamps"].dtype == np.float64
        assert json.loads(str(archive["metadata"]))["nested"] == {"a": [1, 2]}
    loaded = load_recording(path)
    assert np.array_equal(loaded.positions, recording.positions)
    assert np.array_equal(loaded.states, recording.states)
    assert np.array_equal(loaded.timestamps, recording.timestamps)
    assert loaded.metadata == recording.metadata
    if truth:
        assert loaded.ground_truth is not None and recording.ground_truth is not None
        assert np.array_equal(loaded.ground_truth, recording.ground_truth)
    else:
        assert loaded.ground_truth is None
    assert np.array_equal(read_recording(path).positions, recording.positions)


def test_write_appends_npz_suffix(tmp_path: Path, rng: np.random.Generator) -> None:
    path = write_recording(tmp_path / "rec", make_recording(rng))
    assert path.name == "rec.npz" and path.is_file()


def test_properties(rng: np.random.Generator) -> None:
    recording = make_recording(rng)
    assert recording.num_frames == 12
    assert recording.fps == pytest.approx(30.0)
    shares = recording.state_shares()
    assert sum(shares.values()) == pytest.approx(1.0)
    assert shares["inferred"] == pytest.approx(np.mean(recording.states == 1))
    states = recording.states.copy()
    states[4] = 0
    empty = Recording(recording.positions, states, recording.timestamps)
    assert not empty.body_present[4] and empty.body_present[3]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"positions": np.zeros((12, 19, 3))}, "positions: expected shape"),
        ({"positions": np.full((12, 20, 3), np.nan)}, "NaN or inf at frame 0"),
        ({"states": np.full((12, 20), 3)}, "states: expected 0"),
        ({"states": np.zeros((12, 21))}, "states: expected shape"),
        ({"states": np.full((12, 20), 1.5)}, "integers"),
        ({"timestamps": np.arange(12)[::-1] / 30.0}, "must not decrease"),
        ({"timestamps": np.arange(11) / 30.0}, "timestamps: expected shape"),
        ({"ground_truth": np.zeros((11, 20, 3))}, "ground_truth: expected 12 frames"),
        ({"metadata": {"x": object()}}, "JSON"),
    ],
)
def test_invalid_recordings_are_refused(
    rng: np.random.Generator, change: dict[str, object], message: str
) -> None:
    base = make_recording(rng)
    fields = {
        "positions": base.positions,
        "states": base.states,
        "timestamps": base.timestamps,
        "ground_truth": base.ground_truth,
        "metadata": base.metadata,
    }
    fields.update(change)
    with pytest.raises(ValueError, match=message):
        Recording(**fields)  # type: ignore[arg-type]


def _save(path: Path, **arrays: object) -> Path:
    np.savez(path, **arrays)  # type: ignore[arg-type]
    return path


def test_load_errors_name_the_file_and_field(tmp_path: Path, rng: np.random.Generator) -> None:
    good = make_recording(rng)
    base = {
        "positions": good.positions,
        "states": good.states,
        "timestamps": good.timestamps,
        "metadata": np.array(json.dumps(good.metadata)),
    }
    missing = _save(tmp_path / "missing.npz", **{k: v for k, v in base.items() if k != "states"})
    with pytest.raises(DataFormatError, match=r"missing.npz.*missing key\(s\) \['states'\]"):
        load_recording(missing)
    clip = _save(tmp_path / "clip.npz", positions=good.positions, fps=30.0)
    with pytest.raises(DataFormatError, match="simulate"):
        load_recording(clip)
    extra = _save(tmp_path / "extra.npz", **base, bonus=np.zeros(3))
    with pytest.raises(DataFormatError, match="unexpected key"):
        load_recording(extra)
    nan = _save(tmp_path / "nan.npz", **{**base, "positions": np.full((12, 20, 3), np.nan)})
    with pytest.raises(DataFormatError, match=r"nan.npz, field 'positions'.*NaN"):
        load_recording(nan)
    bad_json = _save(tmp_path / "json.npz", **{**base, "metadata": np.array("{not json")})
    with pytest.raises(DataFormatError, match=r"field 'metadata'.*invalid JSON"):
        load_recording(bad_json)
    not_object = _save(tmp_path / "list.npz", **{**base, "metadata": np.array("[1, 2]")})
    with pytest.raises(DataFormatError, match="JSON object"):
        load_recording(not_object)
    pickled = _save(
        tmp_path / "pickle.npz", **{**base, "metadata": np.array([{"a": 1}], dtype=object)}
    )
    with pytest.raises(DataFormatError, match=r"pickle\.npz"):
        load_recording(pickled)
    text = tmp_path / "text.npz"
    text.write_text("not a zip archive")
    with pytest.raises(DataFormatError, match=r"not a readable \.npz"):
        load_recording(text)


def test_head_keeps_the_first_frames() -> None:
    from fpg_gym.io import load_default_clips
    from fpg_gym.simulate import simulate

    recording = simulate(load_default_clips(["punch"])[0], "front-few", seed=1)
    part = recording.head(10)
    assert part.num_frames == 10 and part.metadata["cut_to_frames"] == 10
    assert part.ground_truth is not None and recording.ground_truth is not None
    np.testing.assert_array_equal(part.ground_truth, recording.ground_truth[:10])
    np.testing.assert_array_equal(part.timestamps, recording.timestamps[:10])
    assert recording.head(None) is recording and recording.head(10_000) is recording
    with pytest.raises(ValueError, match="count"):
        recording.head(0)


def test_occluded_mask_round_trips_and_is_checked(tmp_path: Path, rng: np.random.Generator) -> None:
    recording = make_recording(rng, truth=True)
    occluded = np.zeros((12, 20), dtype=bool)
    occluded[3:7, 13:16] = True
    marked = Recording(
        positions=recording.positions,
        states=recording.states,
        timestamps=recording.timestamps,
        ground_truth=recording.ground_truth,
        metadata=recording.metadata,
        occluded=occluded,
    )
    loaded = load_recording(write_recording(tmp_path / "occluded.npz", marked))
    assert loaded.occluded is not None and np.array_equal(loaded.occluded, occluded)
    assert loaded.head(5).occluded is not None and loaded.head(5).occluded.shape == (5, 20)
    with pytest.raises(ValueError, match="occluded: expected shape"):
        Recording(
            recording.positions, recording.states, recording.timestamps, occluded=occluded[:3]
        )
