"""Methods by name, the compare run (files, resume, interruption) and its statistics."""

from __future__ import annotations

import csv
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fpg_gym.core import metrics
from fpg_gym.experiments import (
    CSV_FIELDS,
    TABLE_COLUMNS,
    CompareConfig,
    format_tests,
    plan_episodes,
    run_compare,
)
from fpg_gym.experiments import run as compare_run
from fpg_gym.experiments import stats as compare_stats
from fpg_gym.experiments.distributed import RayUnavailable
from fpg_gym.experiments.store import frames_path
from fpg_gym.io import resolve_clips
from fpg_gym.methods import (
    BASELINE,
    Method,
    MethodRunner,
    expand_methods,
    parse_method,
    reference_bone_lengths,
)

# --------------------------------------------------------------------------- method names


@pytest.mark.parametrize(
    ("text", "name", "is_filter", "selector", "optimizer", "ragdoll"),
    [
        ("raw", "raw", True, None, None, False),
        ("holt:default", "holt", True, None, None, False),
        ("HOLT:very-smoothed+ragdoll", "holt:very-smoothed+ragdoll", True, None, None, True),
        ("kalman:fast", "kalman:fast", True, None, None, False),
        ("one-euro", "one-euro", True, None, None, False),
        ("holt+map", "holt+map", True, None, None, False),
        ("raw+ragdoll+map", "raw+map+ragdoll", True, None, None, True),
        ("fpg", "fpg:local-search", False, "graph", "local-search", False),
        ("shum:cma-es+ragdoll", "shum:cma-es+ragdoll", False, "brute-force", "cma-es", True),
        ("fpg:none", "fpg:none", False, "graph", "none", False),
    ],
)
def test_parse_method(
    text: str,
    name: str,
    is_filter: bool,
    selector: str | None,
    optimizer: str | None,
    ragdoll: bool,
) -> None:
    method = parse_method(text)
    assert method.name == name
    assert parse_method(method.name) == method  # canonical names round-trip
    assert method.is_filter is is_filter
    assert method.selector == selector
    assert method.optimizer == optimizer
    assert method.ragdoll is ragdoll


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("sgd", "unknown base"),
        ("holt:extra-smooth", "preset"),
        ("raw:fast", "preset"),
        ("fpg+physics", "suffix"),
        ("fpg+map", "filters only"),
    ],
)
def test_parse_method_errors(text: str, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_method(text)


def test_expand_methods() -> None:
    names = [
        m.name
        for m in expand_methods(
            ["raw,holt", "fpg"], ["none", "local-search"], ["graph", "brute-force"]
        )
    ]
    assert names == [
        "raw",
        "holt",
        "fpg:local-search",
        "fpg:none",
        "shum:none",
        "shum:local-search",
    ]
    both = [m.name for m in expand_methods(["kalman"], ragdoll="both")]
    assert both == ["kalman", "kalman+ragdoll"]
    assert [m.name for m in expand_methods(["raw"], ragdoll="on")] == ["raw+ragdoll"]
    with pytest.raises(ValueError, match="selector"):
        expand_methods([], ["none"], ["tree"])
    with pytest.raises(ValueError, match="no method"):
        expand_methods([], [], ["graph"])
    assert BASELINE.name == "fpg:local-search"


# --------------------------------------------------------------------------- running methods


@pytest.fixture(scope="module")
def recording() -> Any:
    from fpg_gym.io import load_default_clips
    from fpg_gym.simulate import simulate

    clip = load_default_clips(["walk"])[0]
    return simulate(clip, "front-many", seed=3).head(16)


def test_filter_methods_match_the_filters(recording: Any) -> None:
    from fpg_gym.filters import make_filter

    with MethodRunner() as runner:
        raw = runner.run("raw", recording)
        started = time.perf_counter()
        holt = runner.run("holt:smoothed", recording)
        elapsed_ms = 1e3 * (time.perf_counter() - started)
    assert np.array_equal(raw.poses, recording.positions)
    expected = make_filter("holt:smoothed").filter_sequence(
        recording.positions, recording.states, recording.timestamps
    )
    assert np.allclose(holt.poses, expected)
    assert holt.ms.shape == (recording.num_frames,)
    # Per-frame milliseconds of this run: finite, not negative, together within its wall time.
    assert np.all(np.isfinite(holt.ms)) and np.all(holt.ms >= 0)
    assert 0 < holt.ms.sum() <= elapsed_ms
    assert holt.evaluations is None and list(holt.stage_ms) == ["filter"]


def test_mapped_filters_apply_the_sensor_to_output_map(recording: Any) -> None:
    from fpg_gym.definitions import DefinitionMap
    from fpg_gym.filters import make_filter

    offsets = np.zeros((20, 3))
    offsets[3] = (0.0, 0.05, 0.0)  # the head 5 cm up
    sensor_map = DefinitionMap(offsets, source="sensor", target="database")
    output_map = DefinitionMap(-offsets, source="database", target="vicon")
    with MethodRunner(reconstructor_options={"sensor_map": sensor_map}) as runner:
        mapped = runner.run("raw+map", recording)
        holt = runner.run("holt+map", recording)
    expected = sensor_map.apply(recording.positions)
    assert np.allclose(mapped.poses, expected, atol=1e-6)
    filtered = make_filter("holt").filter_sequence(
        expected.astype(np.float32), recording.states, recording.timestamps
    )
    assert np.allclose(holt.poses, filtered, atol=1e-5)
    both = {"sensor_map": sensor_map, "output_map": output_map}
    with MethodRunner(reconstructor_options=both) as runner:  # composed: back where it was
        assert np.allclose(runner.run("raw+map", recording).poses, recording.positions, atol=1e-5)
    calibrated = {"sensor_map": sensor_map, "calibrate_output": True, "calibration_map": output_map}
    with MethodRunner(reconstructor_options=calibrated) as runner:
        expected = output_map.apply(recording.positions)
        assert np.allclose(runner.run("raw+map", recording).poses, expected, atol=1e-6)
    with MethodRunner() as runner, pytest.raises(ValueError, match="no definition map"):
        runner.run("one-euro+map", recording)


def test_filter_with_ragdoll_has_fixed_bone_lengths(recording: Any) -> None:
    with MethodRunner() as runner:
        result = runner.run("kalman+ragdoll", recording)
    assert list(result.stage_ms) == ["filter", "ragdoll"]
    spread = metrics.bone_length_variation(result.poses)
    assert np.nanmax(spread) < 2e-3  # the ragdoll's bones are rigid
    raw_spread = metrics.bone_length_variation(recording.positions)
    assert np.nanmean(raw_spread) > 5 * np.nanmean(spread)
    lengths = reference_bone_lengths(recording.positions, recording.states)
    assert lengths.shape == (19,) and np.all(lengths > 0.01)


def test_reconstruction_method_is_seeded(recording: Any, graph: Any) -> None:
    with MethodRunner(graph, budget=300) as runner:
        first = runner.run("fpg:random-search", recording, seed=5)
        again = runner.run("fpg:random-search", recording, seed=5)
        other = runner.run("shum:none", recording, seed=5)
    assert first.poses.shape == recording.positions.shape
    assert np.array_equal(first.poses, again.poses)
    assert first.evaluations is not None and np.all(first.evaluations <= 300)
    assert first.evaluations.max() > 0
    assert other.evaluations is not None and np.all(other.evaluations == 0)
    assert "selection" in first.stage_ms and "search" in first.stage_ms


def test_runner_without_graph_refuses_reconstruction(recording: Any) -> None:
    with MethodRunner() as runner, pytest.raises(ValueError, match="graph"):
        runner.run("fpg", recording)


# --------------------------------------------------------------------------- episodes


def test_plan_episodes_ids_and_seeds() -> None:
    episodes = plan_episodes(["walk", "kick"], ["front-many", "left45-many"], [0, 1])
    assert len(episodes) == 8
    assert len({e.id for e in episodes}) == 8
    assert episodes[0].id == "walk__front-many__s0"
    swapped = plan_episodes(["kick", "walk"], ["left45-many", "front-many"], [0, 1])
    seeds = {e.id: e.sim_seed for e in episodes}
    assert all(seeds[e.id] == e.sim_seed for e in swapped)  # order does not matter
    assert len(set(seeds.values())) == 8
    duplicate = plan_episodes(["a", "a"], ["front-few"], [0])
    assert [e.id for e in duplicate] == ["a__front-few__s0", "a__front-few__s0-2"]


def test_resolve_clips_embedded_names() -> None:
    clips, embedded = resolve_clips(["default:walk", "kick"])
    assert [c.name for c in clips] == ["walk", "kick"]
    assert embedded == ["kick", "walk"]
    with pytest.raises(ValueError, match="unknown embedded clip"):
        resolve_clips(["default:moonwalk"])


def test_held_out_warning() -> None:
    class FakeGraph:
        clip_names = ("walk", "run")

    episodes = plan_episodes(["walk", "kick"], ["front-many"], [0])
    assert "walk" in compare_run._held_out_warning(FakeGraph(), episodes)
    assert compare_run._held_out_warning(FakeGraph(), episodes[1:]) == ""


# --------------------------------------------------------------------------- statistics


def test_paired_test() -> None:
    episodes = [f"e{i}" for i in range(8)]
    base = {e: 0.10 + 0.01 * i for i, e in enumerate(episodes)}
    worse = {e: v + 0.02 + 0.001 * i for i, (e, v) in enumerate(base.items())}
    rows = {"fpg:local-search": base, "raw": worse, "same": dict(base)}
    result = compare_stats._paired_test(rows, "raw", "fpg:local-search")
    assert result["paired_episodes"] == 8
    assert result["mean_difference_m"] == pytest.approx(0.0235)
    assert result["lower_error_episodes"] == 0
    # Eight differences, all positive: W- = 0, and the exact two-sided p-value is
    # 2 * P(W- = 0) = 2 / 2**8 = 0.0078125 (a one-sided test would give 1/256 or 1).
    assert result["wilcoxon_p"] == pytest.approx(2 / 2**8, rel=1e-9)
    tie = compare_stats._paired_test(rows, "same", "fpg:local-search")
    assert tie["wilcoxon_p"] is None and "differ" in tie["note"]
    few = {"fpg:local-search": dict(list(base.items())[:3]), "raw": worse}
    small = compare_stats._paired_test(few, "raw", "fpg:local-search")
    assert small["paired_episodes"] == 3 and "cannot fall below 0.05" in small["note"]
    none = compare_stats._paired_test({"raw": worse}, "raw", "fpg:local-search")
    assert none["paired_episodes"] == 0


def test_paired_test_by_hand_with_wins_losses_and_ties() -> None:
    """Signed-rank test worked by hand: two-sided, differences method - baseline, ties dropped.

    Differences (method - baseline), episode by episode: -0.03, -0.01, +0.02, 0, -0.04, +0.05,
    -0.06, 0. Lower error (a win for the method) means a negative difference: 4 wins; the two
    ties are neither wins nor part of the test (``zero_method="wilcox"``). The six non-zero
    differences ranked by size: 0.01 -> 1 (-), 0.02 -> 2 (+), 0.03 -> 3 (-), 0.04 -> 4 (-),
    0.05 -> 5 (+), 0.06 -> 6 (-), so W+ = 2 + 5 = 7 and W- = 14. Of the 2**6 = 64 sign patterns,
    18 have W+ <= 7 (sums 0..7 reached by 1, 1, 1, 2, 2, 3, 4, 4 subsets of {1..6}), so the exact
    two-sided p = 2 * 18 / 64 = 0.5625. One-sided it would be 18/64 or 50/64; keeping the ties
    ("pratt", "zsplit") gives 0.5.
    """
    episodes = [f"e{i}" for i in range(8)]
    differences = [-0.03, -0.01, 0.02, 0.0, -0.04, 0.05, -0.06, 0.0]
    base = {e: 0.25 + 0.01 * i for i, e in enumerate(episodes)}
    method = {e: base[e] + d if d else base[e] for e, d in zip(episodes, differences, strict=True)}
    result = compare_stats._paired_test(
        {"fpg:local-search": base, "mine": method}, "mine", "fpg:local-search"
    )
    assert result["paired_episodes"] == 8
    assert result["mean_difference_m"] == pytest.approx(-0.07 / 8)  # sum of differences / 8
    assert result["lower_error_episodes"] == 4  # ties are not wins
    assert result["wilcoxon_p"] == pytest.approx(36 / 64, rel=1e-9)
    assert result["note"] == ""  # six differing episodes: p can fall below 0.05
    # The same episodes the other way round: the sign flips, wins are the other 2, same p.
    swapped = compare_stats._paired_test(
        {"fpg:local-search": method, "mine": base}, "mine", "fpg:local-search"
    )
    assert swapped["mean_difference_m"] == pytest.approx(0.07 / 8)
    assert swapped["lower_error_episodes"] == 2
    assert swapped["wilcoxon_p"] == pytest.approx(36 / 64, rel=1e-9)
    # The README's paired-test table shows those figures: the signed mean difference (-0.07 / 8
    # = -0.00875 m), the wins out of the paired episodes and p to three digits.
    summary = {
        "method_order": ["fpg:local-search", "mine"],
        "baseline": "fpg:local-search",
        "methods": {"fpg:local-search": {"vs_baseline": {}}, "mine": {"vs_baseline": result}},
    }
    assert format_tests(summary).splitlines()[-1] == "| mine | 8 | -0.0088 | 4 of 8 | 0.562 |"


# --------------------------------------------------------------------------- the run


def _config(out: Path, **changes: Any) -> CompareConfig:
    settings: dict[str, Any] = {
        "out": str(out),
        "methods": ["raw", "holt", "fpg:none", "fpg"],
        "clips": ["default:walk", "default:kick"],
        "scenarios": ["front-many"],
        "max_frames": 12,
        "budget": 200,
        "workers": 1,
    }
    settings.update(changes)
    return CompareConfig(**settings)


def test_compare_writes_results_report_and_plots(tmp_path: Path) -> None:
    out = tmp_path / "run"
    outcome = run_compare(_config(out), progress=False)
    assert outcome.tasks_run == 8 and not outcome.interrupted
    for name in ("results.csv", "summary.json", "report.md", "config.json"):
        assert (out / name).is_file()
    for name in ("error_histogram", "cumulative", "error_over_time", "frame_times"):
        assert (out / f"{name}.png").stat().st_size > 10_000
    with (out / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 8
    assert list(rows[0]) == list(CSV_FIELDS)
    raw = [r for r in rows if r["method"] == "raw"]
    # The raw method's error is the input's error.
    assert all(
        float(r["mean_error_m"]) == pytest.approx(float(r["input_mean_error_m"])) for r in raw
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method_order"] == ["raw", "holt", "fpg:none", "fpg:local-search"]
    assert summary["baseline"] == "fpg:local-search"
    assert len(summary["episodes"]) == 2
    fpg = summary["methods"]["fpg:local-search"]
    assert 0 < fpg["evaluations_per_frame"] <= 200
    assert sum(fpg["band_shares"]) == pytest.approx(1.0)
    assert summary["methods"]["raw"]["evaluations_per_frame"] is None
    # The pooled mean error equals the frame-weighted mean of the rows.
    fpg_rows = [r for r in rows if r["method"] == "fpg:local-search"]
    weights = np.array([float(r["frames"]) for r in fpg_rows])
    means = np.array([float(r["mean_error_m"]) for r in fpg_rows])
    assert fpg["mean_error_m"] == pytest.approx(np.average(means, weights=weights))
    report = (out / "report.md").read_text()
    header = "| " + " | ".join(TABLE_COLUMNS) + " |"
    assert header in report
    assert "Wilcoxon" in report and "![" in report
    assert outcome.table.splitlines()[0] == header
    # Per-joint root-relative error, in the summary and the report.
    raw_joints = summary["methods"]["raw"]["per_joint_root_error_m"]
    assert raw_joints["HipCenter"] == 0.0 and raw_joints["Head"] > 0.0
    assert "## Error per joint (cm)" in report and "| Head |" in report
    assert summary["graph_exclude"] == ["kick", "walk"]  # default graph held them out
    # Lag against the ground truth and bone spread after the first second (issue 15).
    raw_summary = summary["methods"]["raw"]
    assert abs(raw_summary["lag_frames"]) < 3 and raw_summary["lag_ms"] is not None
    assert all(r["lag_frames"] != "" for r in rows)
    assert fpg["settled_bone_spread_mm"] is None  # 12-frame episodes: nothing after 1 s


def test_compare_resumes_and_refuses_other_settings(tmp_path: Path) -> None:
    out = tmp_path / "run"
    config = _config(out, methods=["raw", "holt"])
    assert run_compare(config, progress=False, plots=False).tasks_run == 4
    again = run_compare(config, progress=False, plots=False)
    assert again.tasks_run == 0 and again.tasks_skipped == 4
    more = run_compare(_config(out, methods=["raw", "holt", "kalman"]), progress=False, plots=False)
    assert more.tasks_run == 2 and more.tasks_skipped == 4
    with pytest.raises(ValueError, match="other settings"):
        run_compare(_config(out, methods=["raw"], max_frames=10), progress=False, plots=False)
    fresh = run_compare(_config(out, methods=["raw"], max_frames=10), progress=False, fresh=True)
    assert fresh.tasks_run == 2


def test_compare_interrupted_keeps_finished_rows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = {"n": 0}
    real = compare_run._execute

    def flaky(*args: Any) -> Any:
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(compare_run, "_execute", flaky)
    out = tmp_path / "run"
    outcome = run_compare(_config(out, methods=["raw", "holt"]), progress=False)
    assert outcome.interrupted
    with (out / "results.csv").open() as handle:
        assert len(list(csv.DictReader(handle))) == 2
    assert "Interrupted" in (out / "report.md").read_text()
    monkeypatch.setattr(compare_run, "_execute", real)
    rest = run_compare(_config(out, methods=["raw", "holt"]), progress=False, plots=False)
    assert rest.tasks_run == 2 and rest.tasks_skipped == 2


def test_compare_in_worker_processes(tmp_path: Path) -> None:
    out = tmp_path / "pool"
    outcome = run_compare(
        _config(out, methods=["raw", "fpg:none"], workers=2), progress=False, plots=False
    )
    assert outcome.tasks_run == 4
    single = run_compare(
        _config(tmp_path / "one", methods=["raw", "fpg:none"]), progress=False, plots=False
    )
    for method in ("raw", "fpg:none"):  # same results whatever the process
        assert outcome.summary["methods"][method]["mean_error_m"] == pytest.approx(
            single.summary["methods"][method]["mean_error_m"]
        )


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"methods": []}, "no method"),
        ({"budget": -1}, "budget"),
        ({"max_frames": 2}, "max_frames"),
        ({"clips": []}, "--clips"),
        ({"seeds": [-1]}, "seeds"),
        ({"calibrate_output": True, "output_map": "map.json"}, "give one"),
        ({"calibration_map": "map.json"}, "only used with calibrate_output"),
        ({"batch": 0}, "batch: expected >= 1"),
        ({"backend": "dask"}, "backend: expected one of local, ray"),
        ({"address": "head:6379"}, "address: only used with backend 'ray'"),
    ],
)
def test_config_errors(tmp_path: Path, changes: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        _config(tmp_path, **changes)


def test_unknown_scenario_and_optimizer_fail_early(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="scenario"):
        run_compare(_config(tmp_path / "a", scenarios=["moon"]), progress=False)
    from optimizers import OptimizerNotFound

    with pytest.raises(OptimizerNotFound):
        run_compare(_config(tmp_path / "b", methods=["fpg:gradient"]), progress=False)
    assert not (tmp_path / "b" / "results.csv").exists()


def test_method_dataclass_rejects_unknown_base() -> None:
    with pytest.raises(ValueError, match="unknown base"):
        Method("sgd")


# --------------------------------------------------------------------------- command line


def test_compare_command_reads_argument_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from fpg_gym.cli import main

    listing = tmp_path / "clips.txt"
    listing.write_text("default:walk\ndefault:punch\n")
    out = tmp_path / "cli"
    argv = ["compare", "--clips", f"@{listing}", "--scenarios", "front-many", "--max-frames"]
    argv += ["8", "--methods", "raw,kalman", "--workers", "1", "--out", str(out), "--quiet"]
    assert main([*argv, "--no-plots", "--json"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    summary = json.loads(lines[-1])
    assert summary["episodes"] == 2 and set(summary["methods"]) == {"raw", "kalman"}
    assert lines[0] == "| " + " | ".join(TABLE_COLUMNS) + " |"
    assert main(["compare", "--clips", "default:walk", "--methods", "sgd", "--out", str(out)]) == 2
    assert "unknown base" in capsys.readouterr().err


def test_holdout_split_script(tmp_path: Path) -> None:
    import subprocess
    import sys

    from conftest import REPO, shared_path

    data = shared_path("bandai_namco")
    script = REPO / "scripts" / "holdout_split.py"

    def split(out: Path) -> tuple[list[str], list[str]]:
        subprocess.run(
            [sys.executable, str(script), "--data", str(data), "--out-dir", str(out)],
            check=True,
            capture_output=True,
        )
        graph = (out / "graph_takes.txt").read_text().splitlines()
        held = (out / "eval_takes_all.txt").read_text().splitlines()
        return graph, held

    graph, held = split(tmp_path / "a")
    assert len(graph) + len(held) == 163  # dataset-1, whole files
    assert len(held) == round(0.2 * 163)
    assert not set(graph) & set(held)
    assert all(Path(p).is_file() for p in graph[:3] + held[:3])
    assert split(tmp_path / "b") == (graph, held)  # fixed seed, same lists


def test_prior_suffix() -> None:
    from fpg_gym.methods import parse_method

    method = parse_method("fpg+ragdoll+prior")
    assert method.prior and method.ragdoll and method.name == "fpg:local-search+prior+ragdoll"
    assert parse_method("shum:closed-form+prior").name == "shum:closed-form+prior"
    assert not parse_method("fpg").prior
    with pytest.raises(ValueError, match=r"'\+prior' applies to shum and fpg only"):
        parse_method("holt+prior")


def test_prior_method_uses_the_prior_energy(recording: Any, graph: Any) -> None:
    with MethodRunner(graph, budget=300) as runner:
        plain = runner.run("fpg:closed-form", recording, seed=1)
        prior = runner.run("fpg:closed-form+prior", recording, seed=1)
    assert plain.energy is not None and prior.energy is not None
    # Same pose sought (closed form ignores Ep), so the prior's energy is the plain energy + w Ep.
    assert np.all(prior.energy >= plain.energy - 1e-12)
    assert np.any(prior.energy > plain.energy + 1e-9)


def test_compare_with_a_calibrated_output_runs_and_is_its_own_setting(tmp_path: Path) -> None:
    plain = _config(tmp_path / "plain", methods=["fpg:none"], clips=["default:walk"])
    calibrated = _config(
        tmp_path / "calibrated", methods=["fpg:none"], clips=["default:walk"], calibrate_output=True
    )
    assert calibrated.tuning_options()["calibrate_output"] is True
    assert plain.resume_key() != calibrated.resume_key()  # rows of one never resume the other
    # A packaged graph and map by name are keys themselves (no file to hash).
    named = _config(
        tmp_path / "named",
        methods=["fpg:none"],
        clips=["default:walk"],
        graph="uiprmd",
        sensor_map="kinect-v2-to-vicon",
    )
    key = named.resume_key()
    assert key["graph"] == "uiprmd" and key["sensor_map"] == "packaged:kinect-v2-to-vicon"
    errors = {}
    for name, config in (("plain", plain), ("calibrated", calibrated)):
        outcome = run_compare(config, progress=False, plots=False)
        errors[name] = outcome.summary["methods"]["fpg:none"]["mean_error_m"]
    assert np.isfinite(errors["calibrated"]) and errors["calibrated"] != errors["plain"]


#: Columns of results.csv that are timings (they differ between runs).
TIMING_COLUMNS = ("seconds", "ms_median", "ms_p95", "ms_mean")


def result_rows(out: Path) -> dict[tuple[str, str], dict[str, str]]:
    """results.csv by (episode, method), timing columns left out."""
    with (out / "results.csv").open() as handle:
        return {
            (row["episode"], row["method"]): {
                k: v for k, v in row.items() if k not in TIMING_COLUMNS
            }
            for row in csv.DictReader(handle)
        }


def test_compare_side_by_side_gives_the_rows_of_one_by_one(tmp_path: Path) -> None:
    settings: dict[str, Any] = {"methods": ["raw", "fpg"], "seeds": [0, 1]}
    batched = run_compare(
        _config(tmp_path / "batched", batch=4, **settings), progress=False, plots=False
    )
    alone = run_compare(
        _config(tmp_path / "alone", batch=1, **settings), progress=False, plots=False
    )
    assert batched.tasks_run == alone.tasks_run == 8
    rows = result_rows(tmp_path / "batched")
    assert len(rows) == 8 and rows == result_rows(tmp_path / "alone")
    assert all(float(r["mean_error_m"]) > 0 for r in rows.values())
    # Every per-frame array but the timings is the same.
    for episode, method in rows:
        a = np.load(frames_path(tmp_path / "batched", episode, method))
        b = np.load(frames_path(tmp_path / "alone", episode, method))
        for key in ("poses", "errors", "evaluations", "energy"):
            if key in a.files:
                np.testing.assert_array_equal(a[key], b[key])


def test_ray_backend_without_ray_says_what_to_install(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails
    with pytest.raises(RayUnavailable, match=r"pip install 'fpg-gym\[distributed\]'"):
        run_compare(_config(tmp_path / "run", backend="ray"), progress=False, plots=False)
    assert not (tmp_path / "run" / "episodes").exists()  # failed before simulating
