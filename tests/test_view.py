"""The 3D view (issue 20): a rerun ``.rrd`` written headless and read back."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from fpg_gym.cli import main
from fpg_gym.core import metrics
from fpg_gym.core.outputs import save_npz
from fpg_gym.io import load_default_clips, write_recording
from fpg_gym.simulate import simulate


def recording(frames: int = 20):
    return simulate(load_default_clips(["walk"])[0], "front-many", seed=1).head(frames)


def read_rrd(path: Path) -> dict[str, dict[str, list]]:
    """Entity path -> component column -> values by frame, from rerun's own reader."""
    chunk = pytest.importorskip("rerun.chunk", reason="rerun-sdk >= 0.30 reads .rrd chunks")
    entities: dict[str, dict[int, dict[str, object]]] = {}
    for piece in chunk.RrdReader(str(path)).stream():
        batch = piece.to_record_batch()
        if "frame" not in batch.schema.names:
            continue
        frames = batch.column("frame").to_pylist()
        for name in batch.schema.names:
            if ":" not in name:
                continue
            values = batch.column(name).to_pylist()
            rows = entities.setdefault(piece.entity_path, {})
            for frame, value in zip(frames, values, strict=True):
                rows.setdefault(frame, {})[name.split(":", 1)[1]] = value
    return {
        entity: {
            column: [rows[f][column] for f in sorted(rows)]
            for column in {c for r in rows.values() for c in r}
        }
        for entity, rows in entities.items()
    }


def packed(rgb: np.ndarray) -> list[int]:
    """rerun's u32 RGBA colours."""
    rgb = np.asarray(rgb, dtype=np.uint64)
    return [int(v) for v in (rgb[:, 0] << 24) | (rgb[:, 1] << 16) | (rgb[:, 2] << 8) | 255]


def test_view_file_holds_input_by_state_reconstructions_truth_and_errors(tmp_path: Path) -> None:
    pytest.importorskip("rerun", reason="the 3D view needs rerun-sdk (fpg-gym[view])")
    from fpg_gym.experiments.view import STATE_COLORS, write_view

    rec = recording()
    rng = np.random.default_rng(0)
    estimate = rec.ground_truth + rng.normal(scale=0.02, size=rec.ground_truth.shape)
    path = write_view(
        tmp_path / "view.rrd",
        rec.positions,
        rec.states,
        rec.timestamps,
        reconstructions={"fpg:local-search": estimate, "short": estimate[:5]},
        ground_truth=rec.ground_truth,
    )
    content = read_rrd(path)
    joints = content["/input/joints"]
    assert len(joints["positions"]) == rec.num_frames
    np.testing.assert_allclose(np.array(joints["positions"][7]), rec.positions[7], atol=1e-6)
    for t in (0, 11):
        assert joints["colors"][t] == packed(STATE_COLORS[rec.states[t]])
    assert len(content["/input/bones"]["strips"][3]) == 19
    truth = content["/ground_truth/joints"]["positions"]
    np.testing.assert_allclose(np.array(truth), rec.ground_truth, atol=1e-6)
    methods = [e for e in content if e.startswith("/reconstruction/") and e.endswith("/joints")]
    assert len(methods) == 2
    (long,) = [e for e in methods if "local" in e]
    np.testing.assert_allclose(np.array(content[long]["positions"]), estimate, atol=1e-6)
    (short,) = [e for e in methods if "short" in e]
    assert len(content[short]["positions"]) == 5
    (error,) = [e for e in content if e.startswith("/error/") and "local" in e]
    expected = metrics.frame_error(rec.ground_truth, estimate)
    np.testing.assert_allclose(np.ravel(content[error]["scalars"]), expected, atol=1e-6)


def test_view_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("rerun", reason="the 3D view needs rerun-sdk (fpg-gym[view])")
    rec = recording(12)
    rec_path = write_recording(tmp_path / "rec.npz", rec)
    result = save_npz(tmp_path / "mine.npz", {"poses": rec.ground_truth})
    out = tmp_path / "v.rrd"
    argv = ["view", str(rec_path), "--method", "raw,holt", "--result", str(result)]
    assert main([*argv, "--out", str(out)]) == 0
    content = read_rrd(out)
    shown = {e.split("/")[2] for e in content if e.startswith("/reconstruction/")}
    assert len(shown) == 3 and any("mine" in s for s in shown)
    assert "/ground_truth/joints" in content
    assert "written" in capsys.readouterr().out
    assert main([*argv, "--out", str(tmp_path / "v.png")]) == 2
    assert "expected a .rrd" in capsys.readouterr().err
    assert main(["view", str(rec_path), "--result", str(rec_path), "--out", str(out)]) == 2
    assert "no 'poses' array" in capsys.readouterr().err


def test_view_without_rerun_says_how_to_install(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun -> ImportError
    rec_path = write_recording(tmp_path / "rec.npz", recording(3))
    assert main(["view", str(rec_path), "--out", str(tmp_path / "v.rrd")]) == 2
    assert "pip install 'fpg-gym[view]'" in capsys.readouterr().err
    assert not (tmp_path / "v.rrd").exists()
