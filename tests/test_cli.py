"""The command line: help, the read command, errors; README and CI agree on the test command."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fpg_gym.cli import COMMAND_MODULES, build_parser, main

REPO = Path(__file__).resolve().parents[1]


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for module in COMMAND_MODULES:
        assert module.replace("_", "-") in out


def test_console_script_runs() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "fpg_gym.cli", "--version"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert result.stdout.startswith("fpg-gym ")


def test_read_default_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["read", "default", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["clips"] == 15
    assert summary["frames"] > 900
    assert summary["max_bone_spread_m"] < 1e-3


def test_bad_input_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["read", str(tmp_path / "missing.bvh")]) == 2
    assert "missing.bvh: no such file or folder" in capsys.readouterr().err


def test_parser_builds() -> None:
    assert build_parser().prog == "fpg-gym"


def _fenced_commands(text: str) -> list[str]:
    return re.findall(r"```(?:bash|sh)\n(.*?)\n```", text, flags=re.S)


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    readme = (REPO / "README.md").read_text()
    marker = "<!-- test-command -->"
    assert marker in readme, "README must mark its test command"
    block = _fenced_commands(readme.split(marker, 1)[1])[0].strip()
    assert block in (REPO / ".ci" / "run").read_text()


def test_reconstruct_with_a_reference_filter(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 11: ``fpg-gym reconstruct --method holt`` needs no graph and reports errors."""
    import numpy as np

    from fpg_gym.io import load_default_clips, write_recording
    from fpg_gym.simulate import simulate

    recording = simulate(load_default_clips(["punch"])[0], "front-many", seed=2)
    path = tmp_path / "punch.npz"
    write_recording(path, recording)
    out = tmp_path / "holt.npz"
    assert (
        main(["reconstruct", "--input", str(path), "--method", "holt", "--out", str(out), "--json"])
        == 0
    )
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["method"] == "holt" and summary["frames"] == recording.num_frames
    assert summary["mean_error_m"] > 0
    with np.load(out) as archive:
        assert archive["poses"].shape == recording.positions.shape
    assert main(["reconstruct", "--input", str(path), "--method", "fpg", "--out", str(out)]) == 2
    assert "--graph: a pose graph is needed" in capsys.readouterr().err


def _reconstruct_with_stderr_on(terminal: bool, tmp_path: Path, *flags: str) -> tuple[str, str]:
    """``fpg-gym reconstruct`` of a short simulated walk in a new process, its stderr a
    terminal (a pseudo-terminal) or a pipe: (stdout, stderr)."""
    import fcntl
    import os
    import pty
    import struct
    import termios

    from fpg_gym.io import load_default_clips, write_recording
    from fpg_gym.simulate import simulate

    path = tmp_path / "walk.npz"
    if not path.exists():
        write_recording(path, simulate(load_default_clips(["walk"])[0], "front-many", seed=0))
    argv = [sys.executable, "-m", "fpg_gym.cli", "reconstruct", "--graph", "default"]
    argv += ["--input", str(path), "--no-ragdoll", "--budget", "100"]
    argv += ["--out", str(tmp_path / "out.npz"), *flags]
    if not terminal:
        done = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=True)
        return done.stdout, done.stderr
    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # 100 columns
    try:
        process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=follower, text=True)
        os.close(follower)
        seen = b""
        while True:
            try:
                chunk = os.read(leader, 4096)
            except OSError:  # the terminal closed with the process
                break
            if not chunk:
                break
            seen += chunk
        stdout, _ = process.communicate(timeout=300)
    finally:
        os.close(leader)
    assert process.returncode == 0, seen.decode(errors="replace")
    return stdout, seen.decode(errors="replace")


def test_reconstruct_shows_progress_on_a_terminal_unless_told_not_to(tmp_path: Path) -> None:
    """Issue 39: a progress bar by default when stderr is a terminal; none on a pipe, with
    ``--no-progress`` or ``--quiet`` (which also leaves out the summary lines)."""
    bar = re.compile(r"reconstruct: +\d+%.*frame")
    out, err = _reconstruct_with_stderr_on(True, tmp_path)
    assert bar.search(err), err
    assert "written" in out
    out, err = _reconstruct_with_stderr_on(True, tmp_path, "--no-progress")
    assert not bar.search(err) and "written" in out
    out, err = _reconstruct_with_stderr_on(True, tmp_path, "--quiet", "--json")
    assert not bar.search(err)
    assert len(out.strip().splitlines()) == 1 and json.loads(out)["frames"] == 38
    out, err = _reconstruct_with_stderr_on(False, tmp_path)
    assert not bar.search(err) and "written" in out
    out, err = _reconstruct_with_stderr_on(False, tmp_path, "--progress")
    assert bar.search(err)


def test_readme_and_demo_help_quote_the_same_demo_time() -> None:
    """Issue 39: the README said about 15 s, ``demo --help`` about 30 s; one measurement, with
    its machine and load, in both."""
    from fpg_gym.commands.demo import HELP

    found = re.search(
        r"\((\d+) s, (\d+) CPU s, on a shared 2-core machine at load ([^;]+); (\d+) s the first",
        HELP,
    )
    assert found, HELP
    wall, cpu, load, first = found.groups()
    readme = " ".join((REPO / "README.md").read_text().split())
    assert (
        f"({wall} s of wall time and {cpu} CPU s on this shared 2-core machine at load {load},"
        in readme
    )
    assert f"while numba compiles them in the background, {first} s and" in readme
