"""Hostile input, round 2 (issue 36): the surfaces the first round did not reach.

Each defect of the audit has a test here that failed before its fix: ``compare --no-plots``
listing (and ``--fresh`` deleting) PNGs it never wrote, resume keys that named the graph, a
learned model and the training data by path, a definition map's ``"inverted": "false"``, the
DeepMimic reader's missing range check, a dead Ray address, ``.npz`` bombs. The weak cases
follow: tracebacks, errors naming neither file nor flag, late checks, wrong units, duplicates,
the unlocked compare folder, overwritten files, warning noise. (The reader fuzzing is in
``test_fuzz_readers.py``; round 1 is ``test_hostile_input.py``.)
"""

from __future__ import annotations

import csv
import io
import json
import os
import resource
import signal
import socket
import subprocess
import sys
import time
import warnings
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import exit_status, one_error_line

from fpg_gym.cli import main
from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError, OutputError
from fpg_gym.definitions import DefinitionMap
from fpg_gym.experiments import MANIFEST_NAME, CompareConfig, run_compare
from fpg_gym.experiments.store import Manifest
from fpg_gym.graph import FilteredPoseGraph
from fpg_gym.io import (
    BVH_JOINT_MAP,
    load_default_clips,
    read_bvh,
    read_deepmimic,
    read_positions,
    read_recording,
    write_bvh,
    write_positions,
    write_recording,
)
from fpg_gym.io.deepmimic import default_clip_path
from fpg_gym.io.plausibility import UnusualInputError, accepting_unusual, body_size
from fpg_gym.simulate import simulate

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def recording() -> Any:
    """A short simulated recording with ground truth."""
    return simulate(load_default_clips(["punch"])[0], "front-many", seed=2).head(30)


def _config(out: Path, **changes: Any) -> CompareConfig:
    settings: dict[str, Any] = {
        "out": str(out),
        "methods": ["raw", "holt"],
        "clips": ["default:walk"],
        "scenarios": ["front-many"],
        "max_frames": 12,
        "budget": 50,
        "workers": 1,
    }
    settings.update(changes)
    return CompareConfig(**settings)


def _quiet(_text: str) -> None:
    pass


# --------------------------------------------------------------------------- defect 1


def test_compare_no_plots_neither_lists_nor_claims_pngs(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    source = write_recording(tmp_path / "take.npz", recording)
    out = tmp_path / "run"
    argv = ["compare", "--inputs", str(source), "--methods", "raw", "--workers", "1"]
    assert main([*argv, "--out", str(out), "--quiet", "--no-plots"]) == 0
    printed = capsys.readouterr().out
    assert ".png" not in printed
    manifest = (out / MANIFEST_NAME).read_text()
    assert ".png" not in manifest
    assert not list(out.glob("*.png"))
    # The user's own plot in that folder survives --fresh (compare never wrote it) ...
    (out / "cumulative.png").write_bytes(b"my figure")
    assert main([*argv, "--out", str(out), "--quiet", "--no-plots", "--fresh"]) == 0
    assert (out / "cumulative.png").read_bytes() == b"my figure"
    capsys.readouterr()
    # ... and a run with plots refuses to overwrite it.
    assert main([*argv, "--out", str(out), "--quiet"]) == 2
    line = one_error_line(capsys, "compare")
    assert "cumulative.png" in line and "did not write" in line
    assert (out / "cumulative.png").read_bytes() == b"my figure"
    # Without it, the plots are written, listed and named.
    (out / "cumulative.png").unlink()
    assert main([*argv, "--out", str(out), "--quiet"]) == 0
    written = capsys.readouterr().out
    assert "cumulative.png" in written and "*.png" not in written
    assert "cumulative.png" in (out / MANIFEST_NAME).read_text()


# --------------------------------------------------------------------------- defects 2, 3


def _graph(clips: list[str], path: Path) -> Path:
    return FilteredPoseGraph.build(load_default_clips(clips), thres1=0.3, progress=False).save(path)


def test_compare_keys_the_graph_by_its_content(tmp_path: Path) -> None:
    graph = _graph(["run", "jump"], tmp_path / "g.npz")
    out = tmp_path / "run"
    config = _config(out, methods=["raw", "fpg:none"], graph=str(graph), k=8)
    assert run_compare(config, progress=False, plots=False, log=_quiet).tasks_run == 2
    assert run_compare(config, progress=False, plots=False, log=_quiet).tasks_skipped == 2
    _graph(["kick", "dance_a"], graph)  # another graph under the same name
    with pytest.raises(OutputError, match=r"graph \(its content changed\).*--fresh"):
        run_compare(config, progress=False, plots=False, log=_quiet)
    rerun = run_compare(config, progress=False, plots=False, fresh=True, log=_quiet)
    assert rerun.tasks_run == 2 and rerun.tasks_skipped == 0


@pytest.fixture(scope="module")
def linear_model(graph: Any, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small linear sampler (the default layout: K = 30, 20 axes), saved."""
    from fpg_gym.io import Recording
    from fpg_gym.reconstruct import TemporalConfig
    from policies.imitation import collect_imitation_data
    from policies.pose_sampler import LINEAR_FEATURES, fit_linear
    from policies.sampler import SamplerSpec

    spec = SamplerSpec.for_layout(
        "linear", "ridge", action_mode="absolute", features=list(LINEAR_FEATURES)
    )
    groups = []
    for name in ("run", "jump", "dance_a"):
        truth = load_default_clips([name])[0].positions[:25]
        states = np.full((len(truth), skeleton.NUM_JOINTS), skeleton.TRACKED, np.int8)
        stream = Recording(truth, states, np.arange(len(truth)) / 30.0, ground_truth=truth)
        data = collect_imitation_data(
            graph,
            [stream],
            spec,
            target="bones",
            follow="anchor",
            reconstructor_options={"temporal": TemporalConfig.off()},
        )
        groups.append((data.observations, data.actions, data.episodes))
    sampler, _ = fit_linear(spec, groups)
    return Path(sampler.save(tmp_path_factory.mktemp("model") / "linear")).with_suffix("")


def _linear_files(model: Path, tmp_path: Path) -> Path:
    """A copy of a saved linear sampler in ``tmp_path`` (``model.json`` and ``model.npz``)."""
    copy = tmp_path / "model"
    description = json.loads(model.with_suffix(".json").read_text())
    description["weights"] = "model.npz"
    copy.with_suffix(".json").write_text(json.dumps(description))
    copy.with_suffix(".npz").write_bytes(model.with_suffix(".npz").read_bytes())
    return copy


def test_compare_recomputes_a_learned_method_whose_model_changed(
    tmp_path: Path, linear_model: Path
) -> None:
    model = _linear_files(linear_model, tmp_path)
    learned = f"fpg:learned:{model}"
    config = _config(tmp_path / "run", methods=["raw", learned], max_frames=6)
    assert run_compare(config, progress=False, plots=False, log=_quiet).tasks_run == 2
    assert run_compare(config, progress=False, plots=False, log=_quiet).tasks_skipped == 2
    weights = model.with_suffix(".npz")
    with np.load(weights) as archive:
        arrays = {k: archive[k] for k in archive.files}
    arrays["bias"] = arrays["bias"] + 0.01  # retrained: other weights, same file names
    np.savez(weights, **arrays)
    messages: list[str] = []
    rerun = run_compare(config, progress=False, plots=False, log=messages.append)
    assert rerun.tasks_run == 1 and rerun.tasks_skipped == 1  # raw's row is kept
    assert any("model of" in m and learned in m for m in messages), messages
    rows = list(csv.DictReader((tmp_path / "run" / "results.csv").open()))
    assert sorted(r["method"] for r in rows) == sorted(["raw", learned])


# --------------------------------------------------------------------------- defect 4


def test_train_sampler_checkpoints_key_the_training_data_by_content(tmp_path: Path) -> None:
    from policies.checkpoints import RunCheckpoints
    from policies.training import TrainConfig

    clip = write_positions(tmp_path / "take.npz", load_default_clips(["run"])[0])
    settings = {"kind": "linear", "target": "bones", "follow": "anchor"}
    first = TrainConfig(out=str(tmp_path / "m"), clips=[str(clip), "jump"], **settings)
    RunCheckpoints(tmp_path / "m.checkpoints", first.run_settings())
    write_positions(clip, replace(load_default_clips(["kick"])[0], name="take"))
    second = TrainConfig(out=str(tmp_path / "m"), clips=[str(clip), "jump"], **settings)
    assert first.run_settings()["clips"] == second.run_settings()["clips"]  # same names
    with pytest.raises(ValueError, match="clips_sha256"):
        RunCheckpoints(tmp_path / "m.checkpoints", second.run_settings())
    # Recordings too (a folder of them, read by content).
    folder = tmp_path / "recordings"
    folder.mkdir()
    take = simulate(load_default_clips(["walk"])[0], "front-many", seed=0).head(10)
    write_recording(folder / "a.npz", take)
    paired = {**settings, "recordings": [str(folder)]}
    before = TrainConfig(out=str(tmp_path / "p"), **paired).run_settings()
    write_recording(folder / "a.npz", take.head(9))
    after = TrainConfig(out=str(tmp_path / "p"), **paired).run_settings()
    assert before["recordings_sha256"] != after["recordings_sha256"]


# --------------------------------------------------------------------------- defect 6


@pytest.mark.parametrize("value", ["false", "true", 0, 1, None, [False]])
def test_a_definition_map_inverted_flag_must_be_a_json_boolean(tmp_path: Path, value: Any) -> None:
    data = DefinitionMap.identity("kinect-v2").to_dict()
    data["offsets_m"]["Head"] = [0.0, 0.0, 0.05]
    data["inverted"] = value
    path = tmp_path / "map.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=r"map\.json, field 'inverted': expected true or"):
        DefinitionMap.load(path)
    data["inverted"] = False
    path.write_text(json.dumps(data))
    assert DefinitionMap.load(path).inverted is False


# --------------------------------------------------------------------------- defect 7


def _deepmimic(tmp_path: Path, change: Any) -> Path:
    document = json.loads(default_clip_path("walk").read_text())
    change(document["Frames"])
    path = tmp_path / "humanoid3d_bad.txt"
    path.write_text(json.dumps(document))
    return path


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda f: f[3].__setitem__(1, 1e30), r"frame 3: root position 1e\+30 m"),
        (lambda f: f[2].__setitem__(3, -5e3), r"frame 2: root position 5000 m"),
        (lambda f: f[1].__setitem__(0, 1e9), r"Frames\[1\]\[0\].*frame rate of 1e-09 Hz"),
        (lambda f: f[1].__setitem__(0, 1e-7), r"frame rate of 1e\+07 Hz"),
        (lambda f: f[4].__setitem__(slice(4, 8), [0, 0, 0, 0]), "frame 4: the root rotation"),
        (lambda f: f[0].__setitem__(slice(8, 12), [0, 0, 0, 0]), "frame 0: the chest rotation"),
    ],
)
def test_the_deepmimic_reader_checks_ranges(tmp_path: Path, change: Any, message: str) -> None:
    path = _deepmimic(tmp_path, change)
    start = time.perf_counter()
    with pytest.raises(DataFormatError, match=message) as info:
        read_deepmimic(path)
    assert str(path) in str(info.value)
    assert time.perf_counter() - start < 5.0  # refused before resampling a year of frames


def test_a_real_deepmimic_clip_far_from_the_origin_reads_with_accept_unusual(
    tmp_path: Path,
) -> None:
    def far(frames: list[list[float]]) -> None:
        for frame in frames:
            frame[1] += 2000.0

    path = _deepmimic(tmp_path, far)
    with pytest.raises(DataFormatError, match="root position"):
        read_deepmimic(path)
    with accepting_unusual():
        clip = read_deepmimic(path)
    assert clip.positions[:, 0, 0].min() > 1900.0


# --------------------------------------------------------------------------- defect 8


def _closed_port() -> int:
    """A local TCP port nothing listens on."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def test_a_dead_ray_address_is_refused_quickly(tmp_path: Path, recording: Any) -> None:
    from fpg_gym.runtime.ray_session import RayAddressError, check_address

    address = f"127.0.0.1:{_closed_port()}"
    start = time.perf_counter()
    with pytest.raises(RayAddressError, match=rf"--address {address}: no Ray cluster answers"):
        check_address(address, timeout=2.0)
    with pytest.raises(RayAddressError, match="expected HOST:PORT"):
        check_address("not an address")
    assert time.perf_counter() - start < 3.0
    pytest.importorskip("ray")
    source = write_recording(tmp_path / "take.npz", recording)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-m", "fpg_gym.cli", "compare", "--inputs", str(source)]
    argv += ["--methods", "raw", "--backend", "ray", "--address", address, "--quiet"]
    argv += ["--no-plots", "--out", str(tmp_path / "run")]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=env, cwd=REPO)
    assert done.returncode == 2, done.stderr[-2000:]
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and address in lines[0] and "no Ray cluster answers" in lines[0]


# --------------------------------------------------------------------------- defect 9


def _bomb(path: Path, arrays: dict[str, tuple[tuple[int, ...], str]]) -> Path:
    """An ``.npz`` whose members are zeros of the given shapes, deflated in a stream (a few KB
    on disk for many MB declared) and never held in memory; a ``metadata`` of ``"{}"``."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        buffer = io.BytesIO()
        np.lib.format.write_array(buffer, np.array("{}"))
        archive.writestr("metadata.npy", buffer.getvalue())
        for name, (shape, dtype) in arrays.items():
            header = io.BytesIO()
            np.lib.format.write_array_header_1_0(
                header, {"descr": np.dtype(dtype).str, "fortran_order": False, "shape": shape}
            )
            size = int(np.prod(shape)) * np.dtype(dtype).itemsize
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                member.write(header.getvalue())
                block = bytes(1 << 20)
                for start in range(0, size, len(block)):
                    member.write(block[: min(len(block), size - start)])
    return path


def test_an_npz_bomb_is_refused_before_it_is_inflated(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FPG_GYM_MAX_INPUT_MB", "8")  # the memory ceiling, lowered for the test
    frames = 100_000  # 24 MB of positions in about 25 KB
    arrays = {
        "positions": ((frames, 20, 3), "<f4"),
        "states": ((frames, 20), "|i1"),
        "timestamps": ((frames,), "<f8"),
    }
    bomb = _bomb(tmp_path / "bomb.npz", arrays)
    assert bomb.stat().st_size < 200_000
    with pytest.raises(DataFormatError, match=r"bomb\.npz: the arrays declare 25 MiB.*8 MiB"):
        read_recording(bomb)
    graph = {"poses": ((frames, 20, 3), "<f4")}
    with pytest.raises(DataFormatError, match="refused before inflating"):
        FilteredPoseGraph.load(_bomb(tmp_path / "graph.npz", graph))
    with pytest.raises(DataFormatError, match="refused before inflating"):
        read_positions(_bomb(tmp_path / "clip.npz", {"positions": ((frames, 20, 3), "<f4")}))


def test_npz_shapes_that_do_not_fit_one_another_are_refused_from_the_headers(
    tmp_path: Path,
) -> None:
    arrays = {
        "positions": ((10, 20, 3), "<f4"),
        "states": ((11, 20), "|i1"),
        "timestamps": ((10,), "<f8"),
    }
    with pytest.raises(
        DataFormatError, match=r"field 'states': expected shape \(T, 20\), got \(11, 20\).*T = 10"
    ):
        read_recording(_bomb(tmp_path / "odd.npz", arrays))


def test_a_gzip_bomb_stops_at_the_ceiling(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import gzip

    monkeypatch.setenv("FPG_GYM_MAX_INPUT_MB", "2")
    path = tmp_path / "bomb.bvh.gz"
    path.write_bytes(gzip.compress(b"0 " * (4 << 20)))
    with pytest.raises(DataFormatError, match=r"expands beyond 2 MiB.*FPG_GYM_MAX_INPUT_MB"):
        read_bvh(path, BVH_JOINT_MAP)


# --------------------------------------------------------------------------- plausibility


def _scaled_bvh(tmp_path: Path, factor: float) -> Path:
    """The walk clip as a BVH (centimetres), its lengths multiplied by ``factor``."""
    walk = load_default_clips(["walk"])[0]
    source = write_bvh(tmp_path / "walk_cm.bvh", walk.positions)
    lines = source.read_text().splitlines()
    motion = lines.index("MOTION")
    out = []
    for number, line in enumerate(lines):
        words = line.split()
        if words and words[0] == "OFFSET":
            line = line.replace(line.strip(), " ".join(["OFFSET", *(
                f"{float(v) * factor:.6f}" for v in words[1:])]))  # fmt: skip
        elif number > motion + 2 and words:
            values = [float(v) for v in words]
            values[:3] = [v * factor for v in values[:3]]  # the root's position channels
            line = " ".join(f"{v:.6f}" for v in values)
        out.append(line)
    path = tmp_path / f"walk_x{factor:g}.bvh"
    path.write_text("\n".join(out) + "\n")
    return path


def test_a_millimetre_bvh_is_read_in_metres_and_a_wrong_unit_refused(tmp_path: Path) -> None:
    walk = load_default_clips(["walk"])[0]
    millimetres = _scaled_bvh(tmp_path, 10.0)
    clip = read_bvh(millimetres, BVH_JOINT_MAP)
    assert clip.metadata["scale"] == 0.001
    assert body_size(clip.positions) == pytest.approx(body_size(walk.positions), rel=0.02)
    with pytest.raises(UnusualInputError, match=r"walk_x10\.bvh: the body measures 14\.6"):
        read_bvh(millimetres, BVH_JOINT_MAP, units="cm")
    with accepting_unusual():
        assert body_size(read_bvh(millimetres, BVH_JOINT_MAP, units="cm").positions) > 10


@pytest.mark.parametrize(
    ("factor", "fps", "message"),
    [
        (1000.0, 30.0, r"a coordinate of .*millimetres\? \(1\.47 m as millimetres\)"),
        (100.0, 30.0, r"measures 146\.6 m .*centimetres\?"),
        (1.0, 1e-9, r"field 'fps': a frame rate of 1e-09 Hz"),
        (1.0, 5000.0, r"a frame rate of 5000 Hz; expected 1-1000 Hz"),
    ],
)
def test_positions_in_other_units_or_at_absurd_rates_are_refused(
    tmp_path: Path, factor: float, fps: float, message: str
) -> None:
    walk = load_default_clips(["walk"])[0]
    path = write_positions(
        tmp_path / "walk.npz", replace(walk, positions=walk.positions * factor, fps=fps)
    )
    with pytest.raises(UnusualInputError, match=message) as info:
        read_positions(path)
    assert "--accept-unusual" in str(info.value) and str(path) in str(info.value)
    with accepting_unusual():
        assert read_positions(path).num_frames == walk.num_frames


def test_a_recording_scaled_a_million_times_is_refused_and_the_flag_reads_it(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    huge = replace(
        recording, positions=recording.positions * 1e6, ground_truth=recording.ground_truth
    )
    path = write_recording(tmp_path / "huge.npz", huge)
    with pytest.raises(UnusualInputError, match=r"huge\.npz, field 'positions': a coordinate"):
        read_recording(path)
    argv = ["reconstruct", "--input", str(path), "--method", "raw", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert "--accept-unusual" in one_error_line(capsys, "reconstruct")
    assert main([*argv, "--accept-unusual"]) == 0
    assert os.environ.get("FPG_GYM_ACCEPT_UNUSUAL") is None  # the flag leaves nothing behind


def test_graph_poses_far_away_are_refused_naming_the_file(tmp_path: Path) -> None:
    graph = FilteredPoseGraph.build(load_default_clips(["run"]), thres1=0.3, progress=False)
    graph.poses[3, 5, 1] = 1e30
    path = graph.save(tmp_path / "far.npz")
    with pytest.raises(DataFormatError, match=r"far\.npz, field 'poses': a coordinate of 1e\+30"):
        FilteredPoseGraph.load(path)


# --------------------------------------------------------------------------- weak: tracebacks


def test_a_symlink_loop_as_input_or_graph_is_one_line(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    source = write_recording(tmp_path / "rec.npz", recording)
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    out = str(tmp_path / "o.npz")
    for argv in (
        ["reconstruct", "--input", str(tmp_path / "a"), "--method", "raw", "--out", out],
        ["reconstruct", "--input", str(source), "--graph", str(tmp_path / "a"), "--out", out],
    ):
        assert main(argv) == 2
        assert "a loop of symbolic links" in one_error_line(capsys, "reconstruct")


def test_a_deeply_nested_map_is_one_line(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    source = write_recording(tmp_path / "rec.npz", recording)
    nested = tmp_path / "map.json"
    nested.write_text('{"offsets_m": ' + "[" * 200_000 + "]" * 200_000 + "}")
    argv = ["reconstruct", "--input", str(source), "--graph", "default", "--out"]
    argv += [str(tmp_path / "o"), "--sensor-map", str(nested)]
    assert main(argv) == 2
    assert "map.json: JSON nested too deeply" in one_error_line(capsys, "reconstruct")


def test_a_checkpoint_run_json_whose_settings_are_a_list_is_named(tmp_path: Path) -> None:
    from policies.checkpoints import RUN_FORMAT, RunCheckpoints

    folder = tmp_path / "m.checkpoints"
    folder.mkdir()
    (folder / "run.json").write_text(json.dumps({"format": RUN_FORMAT, "digest": "x",
                                                 "settings": [1, 2]}))  # fmt: skip
    with pytest.raises(DataFormatError, match=r"run\.json, field 'settings'"):
        RunCheckpoints(folder, {"kind": "linear"})
    RunCheckpoints(folder, {"kind": "linear"}, restart=True)  # --restart still starts over


@pytest.mark.parametrize(
    ("array", "value", "message"),
    [
        ("bias", 1e300, r"field 'bias': a value of 1e\+300"),
        ("weights", np.inf, "field 'weights': NaN or inf"),
        ("std", -1.0, "field 'std': expected non-negative"),
    ],
)
def test_absurd_linear_model_values_are_refused(
    tmp_path: Path, linear_model: Path, array: str, value: float, message: str
) -> None:
    from policies.loading import load_sampler

    copy = _linear_files(linear_model, tmp_path)
    with np.load(copy.with_suffix(".npz")) as archive:
        arrays = {k: archive[k] for k in archive.files}
    arrays[array] = arrays[array].copy()
    arrays[array].flat[0] = value
    np.savez(copy.with_suffix(".npz"), **arrays)
    with pytest.raises(DataFormatError, match=message):
        load_sampler(copy)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"hyperparameters": {"min_log_std": 1e308}}, r"min_log_std: expected a number in"),
        ({"hyperparameters": {"max_log_std": "big"}}, r"max_log_std: expected a number"),
        ({"hyperparameters": {"min_log_std": 2.0, "max_log_std": 1.0}}, "is above max_log_std"),
        ({"action_scale": -3.0}, r"action_scale: expected a number in \(0, 1000\]"),
        ({"energy_weights": [1, 0.5, 1e300, 0.25]}, r"energy_weights\[2\]"),
        ({"training": []}, "training: expected a JSON object"),
    ],
)
def test_absurd_supervised_model_settings_are_refused(
    tmp_path: Path, change: dict[str, Any], message: str
) -> None:
    pytest.importorskip("torch")
    from policies.loading import load_sampler
    from policies.sampler import SamplerSpec
    from policies.supervised import SupervisedSampler

    spec = SamplerSpec.for_layout("supervised", "mlp", 4, 5, hyperparameters={"hidden": [8]})
    sampler = SupervisedSampler.create(spec, np.zeros(spec.feature_map().size), np.ones(
        spec.feature_map().size), seed=0)  # fmt: skip
    path = sampler.save(tmp_path / "model")
    data = json.loads(path.read_text())
    for key, value in change.items():
        data[key] = {**data[key], **value} if isinstance(value, dict) else value
    path.write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=message):
        load_sampler(tmp_path / "model")


def test_a_tensor_of_absurd_values_is_refused(tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    from policies.loading import load_sampler
    from policies.sampler import SamplerSpec
    from policies.supervised import SupervisedSampler

    spec = SamplerSpec.for_layout("supervised", "mlp", 4, 5, hyperparameters={"hidden": [8]})
    size = spec.feature_map().size
    sampler = SupervisedSampler.create(spec, np.zeros(size), np.ones(size), seed=0)
    sampler.save(tmp_path / "model")
    state = torch.load(tmp_path / "model.pt", weights_only=True)
    state["mean_head.bias"][0] = float("inf")
    torch.save(state, tmp_path / "model.pt")
    with pytest.raises(DataFormatError, match=r"model\.pt, field 'mean_head\.bias': NaN or inf"):
        load_sampler(tmp_path / "model")


# --------------------------------------------------------------------------- weak: naming


def _fill_disk(limit: int) -> None:  # runs in the child, before exec
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))


@pytest.mark.skipif(sys.platform != "linux", reason="needs RLIMIT_FSIZE (Linux)")
@pytest.mark.parametrize("command", ["simulate", "build-graph"])
def test_a_full_disk_names_the_file_and_keeps_the_old_one(tmp_path: Path, command: str) -> None:
    clip = write_positions(tmp_path / "walk.npz", load_default_clips(["walk"])[0])
    tmp_path = tmp_path / "outputs"
    tmp_path.mkdir()
    out = tmp_path / "out.npz"
    out.write_bytes(b"the previous result")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-m", "fpg_gym.cli", command, str(clip), "--out", str(out)]
    done = subprocess.run(
        argv,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=tmp_path,
        preexec_fn=lambda: _fill_disk(4096),
    )
    assert done.returncode == 2, done.stderr[-2000:]
    errors = [line for line in done.stderr.splitlines() if ": error:" in line]
    assert len(errors) == 1 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert str(out) in errors[0] and "cannot write" in errors[0]
    assert out.read_bytes() == b"the previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.npz"]  # no temporary left


def test_bad_numbers_are_refused_by_the_parser_naming_the_option(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    source = write_recording(tmp_path / "rec.npz", recording)
    base = ["reconstruct", "--input", str(source), "--out", str(tmp_path / "o")]
    listing = ["compare", "--inputs", str(source), "--methods", "raw", "--out", "x"]
    cases = [
        ([*base, "--method", "raw", "--seed", "-1"], "argument --seed: expected an integer >= 0"),
        ([*listing, "--workers", "0"], "argument --workers: expected an integer >= 1"),
        ([*listing, "--workers", "-1"], "argument --workers"),
        ([*listing, "--seeds", "0,0"], "argument --seeds: a seed given twice"),
        (
            [
                "train-sampler",
                "--kind",
                "linear",
                "--latent-dim",
                "0",
                "--out",
                str(tmp_path / "m"),
            ],
            "argument --latent-dim: expected an integer >= 1",
        ),
        ([*base, "--method", "raw", "--optimizer", "cma-es"], "--method raw and --optimizer"),
        ([*base, "--graph", "default", "--optimizer", "learned:"], "learned:MODEL: expected"),
    ]
    for argv, message in cases:
        assert exit_status(argv) == 2, argv
        assert message in one_error_line(capsys, argv[0]), argv
    assert not (tmp_path / "m.checkpoints").exists()
    assert not Path("x").exists()


def test_paths_get_the_message_they_deserve(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str], monkeypatch: Any
) -> None:
    folder = tmp_path / "take.npz"
    folder.mkdir()
    with pytest.raises(DataFormatError, match=r"take\.npz: is a folder; expected a file"):
        read_recording(folder)
    with pytest.raises(DataFormatError, match="is a folder"):
        read_positions(folder)
    with pytest.raises(DataFormatError, match="is a folder"):
        FilteredPoseGraph.load(folder)
    # An unreadable file (permissions; simulated: the tests may run as root).
    source = write_recording(tmp_path / "locked.npz", recording)
    real_open = open

    def locked(file: Any, *args: Any, **kwargs: Any) -> Any:
        if str(file) == str(source):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr("builtins.open", locked)
    for reader in (read_recording, FilteredPoseGraph.load):
        with pytest.raises(DataFormatError, match=r"locked\.npz: cannot read the file \(Perm"):
            reader(source)


def test_a_byte_order_mark_before_hierarchy_is_read(tmp_path: Path) -> None:
    walk = load_default_clips(["walk"])[0]
    plain = write_bvh(tmp_path / "walk.bvh", walk.positions)
    marked = tmp_path / "marked.bvh"
    marked.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    np.testing.assert_array_equal(
        read_bvh(marked, BVH_JOINT_MAP).positions, read_bvh(plain, BVH_JOINT_MAP).positions
    )


# --------------------------------------------------------------------------- weak: late checks


def test_linear_training_with_too_few_clips_is_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: Any
) -> None:
    import policies.training.linear as linear

    def no_work(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("data was collected before the settings were checked")

    monkeypatch.setattr(linear, "imitation_pairs", no_work)
    argv = ["train-sampler", "--kind", "linear", "--target", "bones", "--follow", "anchor"]
    argv += ["--clips", "run", "jump", "--out", str(tmp_path / "m"), "--quiet"]
    assert main(argv) == 2
    assert "needs at least 2 training clips" in one_error_line(capsys, "train-sampler")
    assert not (tmp_path / "m.checkpoints").exists()


def test_fit_map_checks_its_outputs_before_any_work(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    source = write_recording(tmp_path / "rec.npz", recording)
    (tmp_path / "exists").mkdir()
    assert main(["fit-map", str(source), "--out", str(tmp_path / "exists")]) == 2
    assert "is a folder" in one_error_line(capsys, "fit-map")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exists", "rec.npz"]  # no .partial
    assert list((tmp_path / "exists").iterdir()) == []


def test_export_checks_the_timestamps(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    arrays = {
        "positions": recording.positions,
        "states": recording.states,
        "timestamps": recording.timestamps,
        "metadata": np.array("{}"),
    }
    bad = {
        "short": recording.timestamps[:-1],
        "backwards": recording.timestamps[::-1],
        "frozen": np.zeros(recording.num_frames),
        "nan": np.full(recording.num_frames, np.nan),
        "slow": recording.timestamps * 1e9,
    }
    for name, stamps in bad.items():
        path = tmp_path / f"{name}.npz"
        np.savez(path, **{**arrays, "timestamps": stamps})
        argv = ["export", str(path), "--out", str(tmp_path / f"{name}.bvh")]
        assert main(argv) == 2, name
        line = one_error_line(capsys, "export")
        assert f"{name}.npz, field 'timestamps'" in line, line
        assert not (tmp_path / f"{name}.bvh").exists()
    np.savez(tmp_path / "none.npz", positions=recording.positions)
    assert main(["export", str(tmp_path / "none.npz"), "--out", str(tmp_path / "n.csv")]) == 0
    assert "no timestamps in the file: 30 Hz assumed" in capsys.readouterr().out


# --------------------------------------------------------------------------- duplicates


def test_compare_counts_a_repeated_input_once(tmp_path: Path, recording: Any) -> None:
    source = write_recording(tmp_path / "take.npz", recording)
    copy = tmp_path / "copy.npz"
    copy.write_bytes(source.read_bytes())
    messages: list[str] = []
    config = _config(tmp_path / "run", clips=[], inputs=[str(source), str(source), str(copy)])
    outcome = run_compare(config, progress=False, plots=False, log=messages.append)
    assert outcome.summary["episodes"] == ["take__s0"]
    assert outcome.tasks_run == 2  # one episode, two methods
    assert sum("counted once" in m for m in messages) == 2, messages
    with pytest.raises(ValueError, match="seeds: 0 given more than once"):
        _config(tmp_path / "x", seeds=[0, 0])


def test_recordings_of_the_same_name_in_two_folders_stay_two_groups(
    tmp_path: Path, recording: Any
) -> None:
    from policies.paired_recordings import paired_recordings

    takes = {}
    for folder, clip in (("a", "walk"), ("b", "kick"), ("c", "run"), ("d", "jump")):
        (tmp_path / folder).mkdir()
        take = simulate(load_default_clips([clip])[0], "front-many", seed=0).head(8)
        takes[folder] = write_recording(tmp_path / folder / "take.npz", take)
    notes: list[str] = []
    items = [str(tmp_path / f) for f in "abcd"] + [str(takes["a"])]  # a's file twice
    paired = paired_recordings(items, val_share=0.25, log=notes.append)
    groups = paired.info["training_groups"] + paired.info["validation_groups"]
    assert len(groups) == 4 and len(set(groups)) == 4
    assert len(notes) == 1 and "read once" in notes[0]


# --------------------------------------------------------------------------- the compare folder


def test_a_compare_folder_is_locked_while_a_run_writes_there(tmp_path: Path) -> None:
    out = tmp_path / "run"
    run_compare(_config(out), progress=False, plots=False, log=_quiet)
    rows = (out / "results.csv").read_text()
    with Manifest(out):  # another run holds the folder
        for fresh in (False, True):
            with pytest.raises(OutputError, match="another fpg-gym compare is writing"):
                run_compare(_config(out), progress=False, plots=False, fresh=fresh, log=_quiet)
    assert (out / "results.csv").read_text() == rows  # nothing added, nothing deleted
    assert run_compare(_config(out), progress=False, plots=False, log=_quiet).tasks_skipped == 2


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_two_compare_processes_on_one_folder_never_mix_their_rows(tmp_path: Path) -> None:
    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-m", "fpg_gym.cli", "compare", "--clips", "default:walk"]
    argv += ["default:punch", "--scenarios", "front-many", "--methods", "raw,holt,kalman"]
    argv += ["--max-frames", "30", "--workers", "1", "--quiet", "--no-plots", "--out", str(out)]
    first = subprocess.Popen(argv, env=env, cwd=REPO, stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE)  # fmt: skip
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (out / MANIFEST_NAME).exists():
        time.sleep(0.05)
    second = subprocess.run([*argv, "--fresh"], env=env, cwd=REPO, capture_output=True,
                            text=True, timeout=300)  # fmt: skip
    first.communicate(timeout=300)
    if second.returncode == 0:  # the first had finished already: it ran after it, alone
        assert first.returncode == 0
    else:
        assert second.returncode == 2 and "another fpg-gym compare" in second.stderr
        assert first.returncode == 0, "the second run broke the first"
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 6 and len({(r["episode"], r["method"]) for r in rows}) == 6


def test_a_rerun_with_other_methods_reports_what_it_ran(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    run_compare(_config(out, clips=["default:walk", "default:punch"]), progress=False,
                plots=False, log=_quiet)  # fmt: skip
    messages: list[str] = []
    outcome = run_compare(
        _config(out, methods=["raw", "kalman"]), progress=False, plots=False, log=messages.append
    )
    summary = outcome.summary
    assert summary["method_order"] == ["raw", "kalman"]
    assert summary["episodes"] == ["walk__front-many__s0"]
    assert all(m["episodes"] == 1 for m in summary["methods"].values())
    assert summary["rows_not_reported"] == 3  # holt on walk, raw and holt on punch
    assert any("left out of this report" in m for m in messages), messages
    report = (out / "report.md").read_text()
    assert "1 episodes: clips walk" in report and "| holt |" not in report
    assert "also holds 3 row(s) of earlier runs" in report
    assert len(list(csv.DictReader((out / "results.csv").open()))) == 5  # nothing deleted


# --------------------------------------------------------------------------- import-uiprmd


def test_import_uiprmd_never_overwrites_a_file_it_did_not_write(
    tmp_path: Path, rng: np.random.Generator, capsys: pytest.CaptureFixture[str]
) -> None:
    from test_ui_prmd import _markers_for, _standing_joints22, _write_kinect, _write_vicon

    root = tmp_path / "UI-PRMD"
    joints22 = _standing_joints22(60, rng)
    joints22[:, :, 0] += 0.2 * np.sin(np.linspace(0, 6, 60))[:, None]
    _write_kinect(root, "m01_s02_e01", joints22)
    times = np.arange(0, 59 / 30.0, 0.01)
    vicon22 = np.stack([np.interp(times * 30.0, np.arange(60), joints22[:, j, a])
                        for j in range(22) for a in range(3)], 1).reshape(-1, 22, 3)  # fmt: skip
    _write_vicon(root, "m01_s02_e01", _markers_for(vicon22, rng))
    out = tmp_path / "out"
    (out / "recordings").mkdir(parents=True)
    mine = out / "recordings" / "m01_s02_e01.npz"
    mine.write_bytes(b"my own recording")
    argv = ["import-uiprmd", str(root), "--out", str(out), "--workers", "1"]
    assert main(argv) == 2
    assert "m01_s02_e01.npz is there and no earlier import" in one_error_line(
        capsys, "import-uiprmd"
    )
    assert mine.read_bytes() == b"my own recording"
    mine.unlink()
    assert main(argv) == 0
    assert main(argv) == 0  # its own files: replaced
    assert read_recording(mine).ground_truth is not None


# --------------------------------------------------------------------------- warning noise


def test_a_one_frame_recording_gives_no_warning_noise(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    source = write_recording(tmp_path / "one.npz", recording.head(1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for method in ("raw", "holt"):
            argv = ["reconstruct", "--input", str(source), "--method", method]
            assert main([*argv, "--out", str(tmp_path / f"{method}.npz")]) == 0
    printed = capsys.readouterr()
    assert "nan" not in printed.out and "Warning" not in printed.err
