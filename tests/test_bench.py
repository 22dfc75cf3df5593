"""``fpg-gym bench --quick``: every section reports plausible figures."""

from __future__ import annotations

import json

import pytest

from fpg_gym.cli import main
from fpg_gym.experiments.bench import BenchSettings, run_bench
from fpg_gym.experiments.bench_kernels import DIRECT_FRAME
from fpg_gym.experiments.bench_report import format_bench


def test_bench_quick_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--quick", "--quiet", "--json"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    report = json.loads(lines[-1])
    assert not report["interrupted"]
    stages = {row["stage"]: row for row in report["stages"]}
    for stage in ("reliability", "selection", "latent", "search", "ragdoll", "total"):
        assert stage in stages
        assert stages[stage]["graph_median_ms"] > 0
    assert stages["total"]["graph_median_ms"] >= stages["search"]["graph_median_ms"]
    quality = report["stages_quality"]["graph"]
    assert quality["jitter_ms2"] > 0 and quality["mean_error_m"] > 0
    assert quality["lag_frames"] is not None and abs(quality["lag_frames"]) <= 10
    assert any(line.startswith("| graph |") for line in lines)
    selection = report["selection"]
    assert [row["nodes"] for row in selection] == sorted(row["nodes"] for row in selection)
    for row in selection:  # brute force scores every node; graph selection a neighbourhood
        assert row["brute-force_scored"] == row["nodes"]
        assert row["graph_scored"] < row["nodes"]
        assert row["brute_gemv_ms"] > 0 and row["brute_direct_ms"] > 0
        assert row["gemv_speedup"] == row["brute_direct_ms"] / row["brute_gemv_ms"]
        assert 1 <= row["graph_full_searches"] <= row["auto_full_searches"] <= row["queries"]
    assert report["blas_threads"] == 1 and "numpy" in report["energy_kernels"]
    kernels = report["kernels"]
    energy = {row["kernel"]: row for row in kernels["energy"]}
    assert "fused (numpy)" in energy and energy["fused (numpy)"]["us_per_100_points"] > 0
    frame = {row["configuration"]: row for row in kernels["frame"]}
    assert frame[DIRECT_FRAME]["speedup_vs_direct"] == 1.0
    assert any(name.endswith("proposal table (default)") for name in frame)
    assert all(row["cpu_ms_per_frame"] > 0 for row in frame.values())
    assert 5.0 < kernels["floor"]["mflop"] < 20.0 and kernels["floor"]["floor_ms"] > 0
    search = {row["proposals"]: row for row in kernels["search"]}
    assert set(search) == {"normal", "table"}
    for row in search.values():  # the compiled search finds what the ask/tell loop finds
        assert row["problems"] > 0 and row["differ"] == 0
        assert row["loop_ms"] > 0 and row["compiled_ms"] > 0
    assert any(line.startswith("| table |") for line in lines)
    assert any(line.startswith("| fused (numpy) |") for line in lines)
    assert any(line.startswith("CPU time per frame") for line in lines)
    build = report["build"]
    assert all(row["seconds"] > 0 for row in build)
    plain = [row["poses"] for row in build if not row["mirror"]]
    assert plain == sorted(plain) and plain[0] < plain[-1]
    assert report["read"][0]["frames"] == 1013
    assert "steps_per_second" in report["env"][0]
    assert any(line.startswith("| selection |") for line in lines)
    streams = {row["run"]: row for row in report["streams"]}
    assert streams["side by side"]["streams"] == 3 and streams["one by one"]["ratio"] == 1.0
    assert all(row["frames_per_cpu_s"] > 0 for row in streams.values())
    if "numba" in report["energy_kernels"]:  # the same compiled arithmetic, stream by stream
        assert streams["side by side"]["max_difference_m"] == 0.0
    else:
        assert streams["side by side"]["max_difference_m"] < 1e-4
    assert any(line.startswith("| side by side |") for line in lines)


def test_bench_sections_subset_and_format() -> None:
    settings = BenchSettings.make(quick=True)
    settings.sections = ("read",)
    report = run_bench(settings, progress=False)
    assert "stages" not in report and report["read"][0]["frames_per_second"] > 0
    text = format_bench(report)
    assert "Mocap read speed" in text and "Frame time per stage" not in text


def test_bench_rejects_unknown_section(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "--quick", "--sections", "gpu"]) == 2
    assert "unknown gpu" in capsys.readouterr().err
