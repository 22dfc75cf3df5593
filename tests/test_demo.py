"""The reduced demo writes its table, report, plots and GIF."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import imageio.v3 as iio
import pytest

from fpg_gym.cli import main
from fpg_gym.core.compiled import NO_NUMBA_VARIABLE, compiled_module, numba_available
from fpg_gym.experiments import TABLE_COLUMNS
from fpg_gym.experiments.demo import (
    DEMO_METHODS,
    QUICK_GIF_STEP,
    QUICK_METHODS,
    REAL_METHODS,
    demo_recordings,
)
from fpg_gym.experiments.view import rerun_available
from fpg_gym.io.recording import load_recording


def test_quick_demo_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import fpg_gym.experiments.demo as demo

    # On a cold numba cache the demo runs numpy and would leave a compiling process behind.
    monkeypatch.setattr(demo, "compile_in_background", _NotStarted)
    out = tmp_path / "demo"
    assert main(["demo", "--quick", "--out", str(out), "--quiet", "--json"]) == 0
    printed = capsys.readouterr().out
    lines = printed.strip().splitlines()
    summary = json.loads(lines[-1])
    # The printed table has the report's columns and one row per method.
    header = "| " + " | ".join(TABLE_COLUMNS) + " |"
    assert lines.count(header) == 3  # the two real sections, then the simulated one
    start = len(lines) - 1 - lines[::-1].index(header)
    rows = [line for line in lines[start + 2 :] if line.startswith("|")]
    rows = rows[: len(QUICK_METHODS)]
    assert [r.split("|")[1].strip().strip("*") for r in rows] == list(QUICK_METHODS)
    assert all(len(r.strip("|").split("|")) == len(TABLE_COLUMNS) for r in rows)
    assert summary["episodes"] == 2
    assert set(summary["methods"]) == set(QUICK_METHODS)
    for method in QUICK_METHODS:
        assert 0 < summary["methods"][method]["mean_error_m"] < 0.5
    # The real section comes first: the shipped UI-PRMD repetitions against Vicon, as they are
    # and with the legs lost; the default pipeline beats what a Kinect user has on both.
    real = summary["real"]
    assert set(real) == {"clean", "occluded"}
    quick_real = [m for m in REAL_METHODS if m != "holt"]
    for part in real.values():
        assert list(part) == quick_real
    assert printed.index("real Kinect v2 streams") < printed.index("simulated episodes")
    occluded = real["occluded"]
    assert occluded["fpg:closed-form"]["occluded_mpjpe_m"] < occluded["raw"]["occluded_mpjpe_m"]
    assert real["clean"]["fpg:closed-form"]["mpjpe_m"] < real["clean"]["raw"]["mpjpe_m"]
    report = (out / "report.md").read_text()
    assert report.index("## Real Kinect v2 streams") < report.index("## Simulated streams")
    headline = (out / "headline.md").read_text()
    assert "`fpg:closed-form`" in headline and "occluded joints' MPJPE" in headline
    for name in ("clean", "occluded"):
        assert (out / "real" / name / "results.csv").is_file()
    expected = {
        "headline.md",
        "results.csv",
        "summary.json",
        "report.md",
        "config.json",
        "error_histogram.png",
        "cumulative.png",
        "error_over_time.png",
        "frame_times.png",
        "demo.gif",
        "demo_frame.png",
    }
    assert expected <= set(summary["files"])
    assert expected <= {p.name for p in out.iterdir()}
    gif = iio.imread(out / "demo.gif")
    squat = load_recording(demo_recordings()[0])  # the GIF: the real squat with its legs lost
    assert gif.shape[0] == len(range(0, squat.num_frames, QUICK_GIF_STEP))  # every third frame
    assert gif.shape[2] > 2 * gif.shape[1]  # three panels side by side
    assert "time:" in printed
    if rerun_available():  # the 3D view (fpg-gym[view]) comes with the demo when installed
        assert "demo.rrd" in summary["files"]
        assert "3D view" in printed


class _NotStarted:
    """Stands for :func:`fpg_gym.experiments.warm.compile_in_background`'s process."""

    pid = 4242


@pytest.mark.parametrize("cached", [False, True])
def test_a_cold_cache_runs_numpy_and_compiles_in_the_background(
    cached: bool, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With numba's cache cold the demo starts the background compilation and runs every
    reconstruction on the kernels' numpy versions, in this process and in the processes it
    starts; with the cache warm it does neither."""
    import fpg_gym.experiments.demo as demo

    started: list[int] = []
    seen: list[tuple[bool, str | None]] = []

    def compile_in_background() -> _NotStarted:
        started.append(_NotStarted.pid)
        return _NotStarted()

    def run_compare(*args: Any, **kwargs: Any) -> Any:
        hidden = compiled_module("fpg_gym.reconstruct.compiled_kernels") is None
        seen.append((hidden, os.environ.get(NO_NUMBA_VARIABLE)))
        return real_compare(*args, **kwargs)

    real_compare = demo.run_compare
    monkeypatch.delenv(NO_NUMBA_VARIABLE, raising=False)
    monkeypatch.setattr(demo, "warm_kernels_cached", lambda: cached)
    monkeypatch.setattr(demo, "compile_in_background", compile_in_background)
    monkeypatch.setattr(demo, "run_compare", run_compare)
    outcome = demo.run_demo(
        tmp_path / "demo", quick=True, methods=["raw"], progress=False, gif=False, view=False
    )
    assert len(seen) == 3  # the simulated comparison and the two real ones
    if cached:
        assert started == [] and outcome.compiling is None
        assert seen == [(not numba_available(), None)] * 3
    else:
        assert started == [4242] and outcome.compiling == 4242
        assert seen == [(True, "1")] * 3
        assert "numpy versions" in (tmp_path / "demo" / "report.md").read_text()
    assert os.environ.get(NO_NUMBA_VARIABLE) is None


def test_demo_methods_are_valid_names() -> None:
    from fpg_gym.methods import parse_method

    assert "fpg:local-search" in DEMO_METHODS
    assert len(demo_recordings()) == 4  # shipped in the package, subject s08
    for name in DEMO_METHODS + QUICK_METHODS + REAL_METHODS:
        assert parse_method(name).name == name
