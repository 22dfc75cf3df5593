"""Hostile and careless input (issue 16): outputs never destroy inputs, ``compare --fresh``
deletes only its own files, resume trusts no stale state, the readers refuse what is wrong with
file and line, and every bad-input case is one CLI line with exit status 2.

(The model-file cases are in ``test_model_files.py``, the reader fuzzing in
``test_fuzz_readers.py``.)
"""

from __future__ import annotations

import csv
import gzip
import io
import json
import os
import pickle
import signal
import subprocess
import sys
import time
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import exit_status, one_error_line, tiny_bvh

from fpg_gym.cli import main
from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError, FpgGymError, OutputError, TaskError
from fpg_gym.core.outputs import atomic_path, check_output, interrupts_deferred, save_npz
from fpg_gym.experiments import CSV_FIELDS, MANIFEST_NAME, CompareConfig, plan_episodes, run_compare
from fpg_gym.experiments import run as compare_run
from fpg_gym.io import (
    load_clips,
    load_default_clips,
    read_bvh,
    read_recording,
    write_positions,
    write_recording,
)
from fpg_gym.io.kinect import SkippedLinesWarning, write_csv
from fpg_gym.simulate import simulate

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def recording() -> Any:
    """A short simulated recording with ground truth."""
    return simulate(load_default_clips(["punch"])[0], "front-many", seed=2).head(40)


# --------------------------------------------------------------------------- outputs


def test_build_graph_refuses_to_overwrite_its_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clip = write_positions(tmp_path / "walk.npz", load_default_clips(["walk"])[0])
    before = clip.read_bytes()
    assert main(["build-graph", str(clip), "--out", str(clip), "--quiet"]) == 2
    assert "is the input" in one_error_line(capsys, "build-graph")
    assert clip.read_bytes() == before
    # The same file through a folder and another spelling of its path.
    spelled = tmp_path / "." / "walk.npz"
    assert main(["build-graph", str(tmp_path), "--out", str(spelled), "--quiet"]) == 2
    one_error_line(capsys, "build-graph")
    assert clip.read_bytes() == before


@pytest.mark.parametrize("out_name", ["rec.npz", "rec", "./sub/../rec.npz"])
def test_reconstruct_refuses_to_overwrite_its_input(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str], out_name: str
) -> None:
    source = write_recording(tmp_path / "rec.npz", recording)
    (tmp_path / "sub").mkdir()
    before = source.read_bytes()
    out = str(tmp_path / out_name)
    argv = ["reconstruct", "--input", str(source), "--method", "raw", "--out", out]
    assert main(argv) == 2
    assert "is the input" in one_error_line(capsys, "reconstruct")
    assert source.read_bytes() == before


def test_a_symlinked_output_onto_the_input_is_refused(tmp_path: Path, recording: Any) -> None:
    source = write_recording(tmp_path / "rec.npz", recording)
    link = tmp_path / "link.npz"
    link.symlink_to(source)
    with pytest.raises(OutputError, match="is the input"):
        check_output(link, [source], npz=True)


def test_simulate_refuses_to_overwrite_its_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clip = write_positions(tmp_path / "walk.npz", load_default_clips(["walk"])[0])
    before = clip.read_bytes()
    assert main(["simulate", str(clip), "--out", str(tmp_path / "walk")]) == 2
    assert "is the input" in one_error_line(capsys, "simulate")
    assert clip.read_bytes() == before


def test_bad_outputs_are_refused_before_any_work(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str], monkeypatch: Any
) -> None:
    import fpg_gym.io

    source = write_recording(tmp_path / "rec.npz", recording)
    calls = []

    def spy(*args: Any, **kwargs: Any) -> Any:
        calls.append(args)
        raise AssertionError("the input was read before the output was checked")

    monkeypatch.setattr(fpg_gym.io, "read_recording", spy)
    (tmp_path / "folder.npz").mkdir()
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    (tmp_path / "folder").mkdir()
    cases = {
        str(tmp_path / "folder.npz"): "is a folder",
        str(tmp_path / "folder"): "is a folder",
        str(blocker / "out.npz"): "is not a folder",
    }
    if not os.access("/sys", os.W_OK) or not _writable("/sys"):
        cases["/sys/fpg-gym-out.npz"] = "cannot write"
    for out, message in cases.items():
        argv = ["reconstruct", "--input", str(source), "--method", "holt", "--out", out]
        assert main(argv) == 2
        assert message in one_error_line(capsys, "reconstruct")
    assert not calls


def _writable(folder: str) -> bool:
    try:
        with open(Path(folder) / ".fpg-gym-test-probe", "w"):
            pass
    except OSError:
        return False
    (Path(folder) / ".fpg-gym-test-probe").unlink()
    return True


def test_atomic_writes_leave_the_old_file_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as temporary:
        temporary.write_text("half")
        raise RuntimeError("crash while writing")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]


# --------------------------------------------------------------------------- SIGTERM


def test_sigterm_during_reconstruct_keeps_the_frames_done(tmp_path: Path) -> None:
    walk = load_default_clips(["walk"])[0]  # walked there and back, long enough to stop midway
    there_and_back = np.concatenate([walk.positions, walk.positions[::-1]] * 12)
    long = simulate(replace(walk, positions=there_and_back), "front-many", seed=1)
    source = write_recording(tmp_path / "walk.npz", long)
    out = tmp_path / "out.npz"
    env = {**os.environ, "FPG_GYM_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-m", "fpg_gym.cli", "reconstruct", "--input", str(source)]
    argv += ["--graph", "default", "--no-ragdoll", "--budget", "300", "--out", str(out)]
    process = subprocess.Popen(
        [*argv, "--progress"], stderr=subprocess.PIPE, stdout=subprocess.PIPE, env=env, cwd=REPO
    )
    assert process.stderr is not None
    seen = b""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # wait until some frames are done (tqdm's counter)
        chunk = os.read(process.stderr.fileno(), 4096)
        if not chunk:
            break
        seen += chunk
        counts = [int(m) for m in __import__("re").findall(rb"\| *(\d+)/\d+ \[", seen)]
        if counts and max(counts) >= 5:
            break
    process.send_signal(signal.SIGTERM)
    stdout, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, (seen + stderr).decode(errors="replace")[-2000:]
    with np.load(out, allow_pickle=False) as archive:
        frames = len(archive["poses"])
        metadata = json.loads(str(archive["metadata"]))
    assert 5 <= frames < long.num_frames
    assert metadata["interrupted"] is True and metadata["frames"] == frames
    assert b"(interrupted)" in stdout


def test_kill_9_during_reconstruct_keeps_the_last_checkpoint(tmp_path: Path) -> None:
    walk = load_default_clips(["walk"])[0]
    long = simulate(replace(walk, positions=np.concatenate([walk.positions] * 20)), "front-many")
    source = write_recording(tmp_path / "walk.npz", long)
    out = tmp_path / "out.npz"
    env = {**os.environ, "FPG_GYM_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-m", "fpg_gym.cli", "reconstruct", "--input", str(source), "--graph",
            "default", "--no-ragdoll", "--budget", "300", "--out", str(out),
            "--checkpoint-s", "0.2"]  # fmt: skip
    process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    deadline = time.monotonic() + 120
    while not out.exists() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    process.kill()  # SIGKILL: no handler runs
    process.wait(timeout=30)
    with np.load(out, allow_pickle=False) as archive:  # a whole archive, never a torn one
        frames = len(archive["poses"])
        metadata = json.loads(str(archive["metadata"]))
    assert 0 < frames < long.num_frames
    assert metadata["partial"] is True and metadata["frames"] == frames


def test_an_interrupt_during_the_final_write_waits_until_it_is_written(tmp_path: Path) -> None:
    written = tmp_path / "out.npz"
    with pytest.raises(KeyboardInterrupt), interrupts_deferred():
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)
        save_npz(written, {"poses": np.zeros((3, 20, 3))})
    with np.load(written, allow_pickle=False) as archive:
        assert archive["poses"].shape == (3, 20, 3)
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # handlers given back


# --------------------------------------------------------------------------- compare


def _config(out: Path, **changes: Any) -> CompareConfig:
    settings: dict[str, Any] = {
        "out": str(out),
        "methods": ["raw", "holt"],
        "clips": ["default:walk"],
        "scenarios": ["front-many"],
        "max_frames": 12,
        "budget": 100,
        "workers": 1,
    }
    settings.update(changes)
    return CompareConfig(**settings)


def test_compare_fresh_refuses_a_folder_it_did_not_create(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "mine"
    (folder / "episodes").mkdir(parents=True)
    source = write_recording(folder / "episodes" / "take.npz", recording)
    (folder / "frames").mkdir()
    (folder / "frames" / "keep.txt").write_text("mine")
    (folder / "report.md").write_text("my notes")
    before = sorted(str(p) for p in folder.rglob("*"))
    argv = ["compare", "--inputs", str(source), "--methods", "raw", "--workers", "1"]
    assert main([*argv, "--out", str(folder), "--fresh", "--quiet", "--no-plots"]) == 2
    assert "did not write" in one_error_line(capsys, "compare")
    assert sorted(str(p) for p in folder.rglob("*")) == before
    assert (folder / "report.md").read_text() == "my notes"
    # Without --fresh it refuses too: it would overwrite report.md.
    assert main([*argv, "--out", str(folder), "--quiet", "--no-plots"]) == 2
    one_error_line(capsys, "compare")
    assert (folder / "report.md").read_text() == "my notes"


def test_compare_fresh_deletes_only_what_compare_wrote(tmp_path: Path) -> None:
    out = tmp_path / "run"
    first = run_compare(_config(out), progress=False, plots=False)
    assert first.tasks_run == 2
    listed = (out / MANIFEST_NAME).read_text().splitlines()
    assert "results.csv" in listed and "config.json" in listed
    assert any(line.startswith("frames/") for line in listed)
    (out / "notes.txt").write_text("mine")
    (out / "frames" / "mine.txt").write_text("mine")
    episode = out / "frames" / "walk__front-many__s0"
    leftover = episode / ".raw.npz.4242.0badc0de.tmp"  # a kill during a write left it
    leftover.write_bytes(b"partial")
    (episode / ".mine.tmp").write_text("mine")
    again = run_compare(_config(out), progress=False, plots=False, fresh=True)
    assert again.tasks_run == 2 and again.tasks_skipped == 0
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "frames" / "mine.txt").read_text() == "mine"
    assert (episode / ".mine.tmp").read_text() == "mine"
    assert not leftover.exists()


def test_a_compare_folder_of_an_earlier_version_resumes_but_is_never_wiped(
    tmp_path: Path,
) -> None:
    out = tmp_path / "run"
    run_compare(_config(out), progress=False, plots=False)
    (out / MANIFEST_NAME).unlink()  # as an fpg-gym without manifests left it
    config = json.loads((out / "config.json").read_text())
    for episode in config["episodes"]:
        del episode["key"]
    (out / "config.json").write_text(json.dumps(config))
    with pytest.raises(OutputError, match="--fresh deletes only files listed"):
        run_compare(_config(out), progress=False, plots=False, fresh=True)
    assert (out / "results.csv").is_file()
    messages: list[str] = []
    resumed = run_compare(_config(out), progress=False, plots=False, log=messages.append)
    assert any("earlier fpg-gym compare" in m for m in messages), messages
    assert resumed.tasks_run == 2  # no content key: recomputed, not trusted
    assert (out / MANIFEST_NAME).is_file()
    assert run_compare(_config(out), progress=False, plots=False).tasks_skipped == 2


def test_argument_file_lines_are_never_options(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    run_compare(_config(out), progress=False, plots=False)
    listing = tmp_path / "clips.txt"
    listing.write_text("default:walk\n--fresh\n")
    argv = ["compare", "--clips", f"@{listing}", "--scenarios", "front-many"]
    argv += ["--methods", "raw,holt", "--max-frames", "12", "--budget", "100"]
    assert main([*argv, "--workers", "1", "--out", str(out), "--quiet", "--no-plots"]) == 2
    line = one_error_line(capsys, "compare")
    assert "clips.txt, line 2" in line and "never options" in line
    assert len(list(csv.DictReader((out / "results.csv").open()))) == 2  # nothing deleted


def test_a_torn_last_row_is_repaired_with_a_warning(tmp_path: Path) -> None:
    out = tmp_path / "run"
    run_compare(_config(out, clips=["default:walk", "default:punch"]), progress=False, plots=False)
    results = out / "results.csv"
    raw = results.read_bytes()
    results.write_bytes(raw[: len(raw) - 40])  # kill -9 in the middle of the last row
    messages: list[str] = []
    rerun = run_compare(
        _config(out, clips=["default:walk", "default:punch"]),
        progress=False,
        plots=False,
        log=messages.append,
    )
    assert any("cut off" in m and "results.csv" in m for m in messages), messages
    assert rerun.tasks_run == 1 and rerun.tasks_skipped == 3
    with results.open(newline="") as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == list(CSV_FIELDS)
    assert all(len(row) == len(CSV_FIELDS) for row in rows)
    keys = [(row[0], row[4]) for row in rows[1:]]
    assert len(keys) == 4 and len(set(keys)) == 4
    assert all(row[4] in ("raw", "holt") for row in rows[1:])


def test_a_different_recording_under_the_same_name_is_not_reused(
    tmp_path: Path, recording: Any
) -> None:
    out = tmp_path / "run"
    source = write_recording(tmp_path / "take.npz", recording)
    config = _config(out, clips=[], inputs=[str(source)])
    assert run_compare(config, progress=False, plots=False).tasks_run == 2
    other = simulate(load_default_clips(["kick"])[0], "front-many", seed=5).head(30)
    write_recording(source, other)
    messages: list[str] = []
    rerun = run_compare(config, progress=False, plots=False, log=messages.append)
    assert rerun.tasks_run == 2 and rerun.tasks_skipped == 0
    assert any("changed" in m for m in messages), messages
    episode = read_recording(out / "episodes" / "take__s0.npz")
    np.testing.assert_array_equal(episode.positions, other.head(12).positions)
    rows = list(csv.DictReader((out / "results.csv").open()))
    assert len(rows) == 2 and {r["input_frames"] for r in rows} == {"12"}
    # The same content again: everything is kept.
    assert run_compare(config, progress=False, plots=False).tasks_skipped == 2


def test_two_clips_with_the_same_file_name_stay_distinct(tmp_path: Path) -> None:
    walk, kick = load_default_clips(["walk", "kick"])
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    # Two takes named alike in two folders (as a/move.bvh and b/move.bvh are).
    first = write_positions(tmp_path / "a" / "move.npz", replace(walk, name="move"))
    second = write_positions(tmp_path / "b" / "move.npz", replace(kick, name="move"))
    out = tmp_path / "run"
    outcome = run_compare(
        _config(out, clips=[str(first), str(second)], methods=["raw"]),
        progress=False,
        plots=False,
        log=lambda _: None,
    )
    assert outcome.tasks_run == 2
    episodes = outcome.summary["episodes"]
    assert len(episodes) == 2 and all(e.startswith("move_") for e in episodes)
    # Two recordings with the same file name too.
    one = write_recording(tmp_path / "a" / "rec.npz", simulate(walk, "front-few", seed=0).head(9))
    two = write_recording(tmp_path / "b" / "rec.npz", simulate(kick, "front-few", seed=0).head(9))
    planned = plan_episodes([], [], [0], [str(one), str(two)], ["1" * 64, "2" * 64])
    assert [e.id for e in planned] == ["rec_11111111__s0", "rec_22222222__s0"]
    swapped = plan_episodes([], [], [0], [str(two), str(one)], ["2" * 64, "1" * 64])
    assert {e.id: e.recording for e in swapped} == {e.id: e.recording for e in planned}


def test_a_failing_task_names_its_episode_and_method(tmp_path: Path, monkeypatch: Any) -> None:
    real = compare_run._execute

    def failing(runner: Any, task: Any, recording: Any) -> Any:
        if task.method == "holt":
            raise RuntimeError("boom")
        return real(runner, task, recording)

    monkeypatch.setattr(compare_run, "_execute", failing)
    with pytest.raises(TaskError, match=r"episode 'walk__front-many__s0'.*method 'holt'.*boom"):
        run_compare(_config(tmp_path / "run"), progress=False, plots=False)


def _children(parent: int) -> list[int]:
    """Worker processes (multiprocessing spawn) whose parent is ``parent``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            command = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == parent and b"spawn_main" in command:
            found.append(int(entry.name))
    return found


def _alive(pid: int) -> bool:
    try:
        state = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _wait_for_workers(parent: subprocess.Popen[Any], count: int) -> list[int]:
    workers: list[int] = []
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(workers) < count and parent.poll() is None:
        time.sleep(0.5)
        workers = _children(parent.pid)
    return workers


def _reap(workers: list[int], seconds: float) -> list[int]:
    """The workers still alive after ``seconds`` (killed then, to leave nothing behind)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and any(_alive(pid) for pid in workers):
        time.sleep(0.5)
    left = [pid for pid in workers if _alive(pid)]
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    return left


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_sigterm_stops_compare_and_its_workers_and_keeps_a_report(tmp_path: Path) -> None:
    out = tmp_path / "run"
    env = {**os.environ, "FPG_GYM_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-m", "fpg_gym.cli", "compare", "--clips", "default:walk"]
    argv += ["default:punch", "default:kick", "--scenarios", "front-many", "--methods"]
    argv += ["raw,fpg:local-search", "--workers", "2", "--out", str(out), "--quiet", "--no-plots"]
    parent = subprocess.Popen(
        argv, env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    workers = _wait_for_workers(parent, 2)
    assert len(workers) == 2, "the workers did not start"
    deadline = time.monotonic() + 60  # until some task finished
    while time.monotonic() < deadline and not list((out / "frames").rglob("*.npz")):
        time.sleep(0.3)
    parent.send_signal(signal.SIGTERM)
    _, stderr = parent.communicate(timeout=60)
    assert parent.returncode == 130, stderr.decode(errors="replace")[-2000:]
    assert not _reap(workers, 10), "compare's workers outlived SIGTERM"
    assert "Interrupted" in (out / "report.md").read_text()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
def test_compare_workers_exit_when_the_parent_is_killed(tmp_path: Path) -> None:
    script = (
        "import sys\n"
        "from fpg_gym.experiments import CompareConfig, run_compare\n"
        f"config = CompareConfig(out={str(tmp_path / 'run')!r}, methods=['fpg:local-search'], "
        "clips=['default:walk', 'default:punch', 'default:kick'], scenarios=['front-many'], "
        "budget=2000, workers=2)\n"
        "run_compare(config, progress=False, plots=False)\n"
    )
    env = {**os.environ, "FPG_GYM_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(REPO)}
    parent = subprocess.Popen([sys.executable, "-c", script], env=env, cwd=REPO)
    workers = _wait_for_workers(parent, 2)
    assert len(workers) == 2, "the workers did not start"
    time.sleep(1.0)
    parent.kill()  # SIGKILL: no chance to stop its workers
    parent.wait()
    assert not _reap(workers, 20), "compare's workers outlived their killed parent"


# --------------------------------------------------------------------------- BVH

_BVH = tiny_bvh(
    [
        "0 100 0 0 0 0 0 0 0 0 0 0",
        "10 100 0 0 0 90 90 90 0 0 0 0",
        "20 100 0 0 0 90 90 90 0 0 0 0",
    ]
)
_ANY_MAP = {name: "Hips" for name in skeleton.JOINT_NAMES}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (_BVH.replace("10 100 0 0 0 90", "10 1e30 0 0 0 90"), r"line 25: value 1e\+30 is beyond"),
        (_BVH.replace("10 100 0 0 0 90", "10 1e39 0 0 0 90"), r"line 25: value 1e\+39 is beyond"),
        (_BVH.replace("JOINT Hand", "JOINT Chest"), r"line 10: duplicate joint name 'Chest'"),
        (
            _BVH.replace("10 100 0 0 0 90 90 90 0 0 0 0\n20", "10 100 0 0 0 90 90 90 0 0 0\n0 20"),
            r"line 25: expected 12 values per frame line.*got 11",
        ),
        (_BVH.replace("Frame Time: 0.0333333", "Frame Time: 1e9"), "line 23: frame time"),
        (_BVH.replace("Frames: 3", "Frames: 100000"), "truncated: header says 100000 frames"),
        (_BVH.replace("Frames: 3", "Frames: 1000000000"), r"line 22: 1000000000 frames .* last"),
    ],
)
def test_bvh_that_should_be_refused_is_refused(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(DataFormatError, match=message) as info:
        read_bvh(path, _ANY_MAP)
    assert str(path) in str(info.value)


def test_a_bad_file_in_a_folder_read_in_parallel_is_named(tmp_path: Path) -> None:
    for name in ("a", "b", "c", "d", "e"):
        (tmp_path / f"{name}.bvh").write_text(_BVH)
    (tmp_path / "c.bvh").write_text(_BVH.replace("10 100 0 0 0 90", "10 nan 0 0 0 90"))
    with pytest.raises(DataFormatError, match=r"c\.bvh, line 25: NaN or inf"):
        load_clips([tmp_path], workers=2, progress=False, joint_map=_ANY_MAP)


def test_project_errors_survive_pickling() -> None:
    errors: list[FpgGymError] = [
        DataFormatError("x.bvh", "bad value", line=3),
        DataFormatError("x.npz", "bad", field="positions"),
        OutputError("--out x: is a folder"),
        TaskError("episode 'e', method 'm' failed"),
    ]
    for error in errors:
        copy = pickle.loads(pickle.dumps(error))
        assert type(copy) is type(error) and str(copy) == str(error)
    copy = pickle.loads(pickle.dumps(errors[0]))
    assert isinstance(copy, DataFormatError) and (copy.path, copy.line) == ("x.bvh", 3)


# --------------------------------------------------------------------------- Kinect readers


def _msrc12_text(recording: Any) -> list[str]:
    lines = []
    to_file = np.argsort(skeleton.FROM_KINECT_V1)  # Kinect-20 order -> the file's v1 order
    for t, frame in enumerate(recording.positions[:, to_file]):
        values = np.concatenate([frame, np.ones((len(frame), 1))], axis=1).ravel()
        lines.append(" ".join([str(1000 * t), *(f"{v:.4f}" for v in values)]))
    return lines


def test_a_cut_or_nan_first_line_does_not_decide_the_format(tmp_path: Path, recording: Any) -> None:
    lines = _msrc12_text(recording)
    cut = tmp_path / "cut.txt"
    cut.write_text("\n".join([lines[0][: len(lines[0]) // 2], *lines[1:]]) + "\n")
    nan = tmp_path / "nan.txt"
    nan.write_text("\n".join([" ".join(["NaN"] * 81), *lines[1:]]) + "\n")
    for path in (cut, nan):
        with pytest.warns(SkippedLinesWarning, match="line 1"):
            read = read_recording(path)
        assert read.metadata["format"] == "msrc12" and read.num_frames == len(lines) - 1
    with pytest.warns(SkippedLinesWarning):
        assert read_recording(cut, format="msrc12").num_frames == len(lines) - 1


def test_reconstruct_format_choices_match_the_readers() -> None:
    from fpg_gym.commands.reconstruct import KINECT_FORMATS
    from fpg_gym.io.kinect import KINECT_FORMATS as READERS

    assert KINECT_FORMATS == READERS


def test_coordinates_beyond_float32_are_named_with_file_and_line(
    tmp_path: Path, recording: Any
) -> None:
    lines = _msrc12_text(recording)
    fields = lines[3].split()
    fields[5] = "3.5e38"
    lines[3] = " ".join(fields)
    path = tmp_path / "big.txt"
    path.write_text("\n".join(lines) + "\n")
    with pytest.warns(SkippedLinesWarning, match=r"coordinate beyond.*line 4"):
        read = read_recording(path)
    assert read.num_frames == len(lines) - 1 and np.all(np.isfinite(read.positions))
    arrays = {
        "positions": recording.positions.astype(np.float64),
        "states": recording.states,
        "timestamps": recording.timestamps,
        "metadata": np.array("{}"),
    }
    arrays["positions"][2, 3, 1] = 1e39
    np.savez(tmp_path / "big.npz", **arrays)
    with pytest.raises(DataFormatError, match=r"big\.npz.*positions.*1e\+39.*float32"):
        read_recording(tmp_path / "big.npz")


def test_corrupt_gzip_is_a_project_error_naming_the_file(tmp_path: Path, recording: Any) -> None:
    csv_path = write_csv(tmp_path / "rec.csv", recording)
    packed = bytearray(gzip.compress(csv_path.read_bytes()))
    packed[30:60] = bytes(b ^ 0xFF for b in packed[30:60])
    path = tmp_path / "rec.csv.gz"
    path.write_bytes(bytes(packed))
    with pytest.raises(DataFormatError, match=r"rec\.csv\.gz: corrupt gzip"):
        read_recording(path)


def test_a_gzip_bomb_is_refused(tmp_path: Path, monkeypatch: Any) -> None:
    monkeypatch.setenv("FPG_GYM_MAX_INPUT_MB", "1")  # the memory ceiling, lowered
    path = tmp_path / "bomb.bvh.gz"
    path.write_bytes(gzip.compress(b"0 " * (1 << 20)))  # 2 MiB from 2 KiB
    with pytest.raises(DataFormatError, match=r"bomb\.bvh\.gz: gzip data expands beyond 1 MiB"):
        read_bvh(path, _ANY_MAP)


def test_an_absurd_ntu_frame_count_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "huge.skeleton"
    path.write_text("1000000000\n0\n0\n")
    start = time.perf_counter()
    with pytest.raises(DataFormatError, match=r"huge\.skeleton, line 1: the header declares"):
        read_recording(path)
    assert time.perf_counter() - start < 1.0


def test_a_forged_npz_array_header_is_a_clear_error(tmp_path: Path, recording: Any) -> None:
    path = write_recording(tmp_path / "rec.npz", recording)
    forged = tmp_path / "forged.npz"
    with zipfile.ZipFile(path) as source, zipfile.ZipFile(forged, "w") as target:
        for info in source.infolist():
            data = source.read(info)
            if info.filename == "positions.npy":
                header = io.BytesIO()
                np.lib.format.write_array_header_1_0(
                    header, {"descr": "<f4", "fortran_order": False, "shape": (10**12, 20, 3)}
                )
                data = header.getvalue() + b"\0" * 64
            target.writestr(info.filename, data)
    with pytest.raises(DataFormatError, match=r"forged\.npz, field 'positions'.*announces"):
        read_recording(forged)
    from fpg_gym.graph import FilteredPoseGraph
    from fpg_gym.io import read_positions

    with pytest.raises(DataFormatError, match="announces"):
        read_positions(forged)
    with pytest.raises(DataFormatError, match="forged"):
        FilteredPoseGraph.load(forged)


# --------------------------------------------------------------------------- the CLI


def test_every_bad_input_is_one_line_with_status_2(
    tmp_path: Path, recording: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    source = write_recording(tmp_path / "rec.npz", recording)
    bad_bvh = tmp_path / "bad.bvh"
    bad_bvh.write_text(_BVH.replace("JOINT Hand", "JOINT Chest"))
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"PK\x03\x04 not really")
    gz = tmp_path / "broken.txt.gz"
    gz.write_bytes(gzip.compress(b"1 2 3\n" * 100)[:25])
    cases = [
        ("read", ["read", str(bad_bvh)]),
        ("read", ["read", "--no-such-option", "default"]),
        ("build-graph", ["build-graph", str(bad_bvh), "--out", str(tmp_path / "g.npz")]),
        ("reconstruct", ["reconstruct", "--input", str(garbage), "--method", "raw", "--out", "x"]),
        ("reconstruct", ["reconstruct", "--input", str(gz), "--method", "raw", "--out", "x"]),
        (
            "reconstruct",
            ["reconstruct", "--input", str(source), "--graph", str(garbage), "--out", "y"],
        ),
        (
            "reconstruct",
            ["reconstruct", "--input", str(source), "--method", "raw", "--format", "bvh"],
        ),
        ("simulate", ["simulate", str(tmp_path / "missing.bvh"), "--out", "z"]),
        ("read", ["read", f"@{tmp_path / 'no-list.txt'}"]),
    ]
    for command, argv in cases:
        assert exit_status(argv) == 2, argv
        one_error_line(capsys, command)
    assert not Path("x.npz").exists() and not Path("y.npz").exists()


def test_argparse_errors_exit_2_on_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["reconstruct", "--input", "x.npz", "--format", "bvh", "--out", "o.npz"])
    assert info.value.code == 2
    one_error_line(capsys, "reconstruct")
