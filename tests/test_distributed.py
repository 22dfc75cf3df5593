"""compare --backend ray on a local Ray instance started by the test: the same results.csv rows
(timings aside) as the local backend."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from fpg_gym.core.errors import TaskError
from fpg_gym.experiments import run_compare
from fpg_gym.experiments.distributed import restore_signals, run_on_ray, signal_handlers
from tests.test_compare import _config, result_rows

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'fpg-gym[distributed]')")


@pytest.fixture(scope="module")
def local_ray() -> Iterator[Any]:
    handlers = signal_handlers()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
    restore_signals(handlers)  # Ray's driver installs its own SIGTERM handler


def test_ray_backend_writes_the_rows_of_the_local_backend(tmp_path: Path, local_ray: Any) -> None:
    settings: dict[str, Any] = {"methods": ["raw", "fpg"], "seeds": [0, 1], "batch": 2}
    on_ray = run_compare(
        _config(tmp_path / "ray", backend="ray", **settings), progress=False, plots=False
    )
    # Local worker processes, which run BLAS on one thread as Ray's workers do (a sum over
    # threads may round its last digit otherwise).
    local = run_compare(
        _config(tmp_path / "local", workers=2, **settings), progress=False, plots=False
    )
    assert on_ray.tasks_run == local.tasks_run == 8 and not on_ray.interrupted
    rows = result_rows(tmp_path / "ray")
    assert len(rows) == 8 and rows == result_rows(tmp_path / "local")
    assert all(float(r["mean_error_m"]) > 0 for r in rows.values())
    # Resumable like the local backend: a rerun finds every row done.
    again = run_compare(
        _config(tmp_path / "ray", backend="ray", **settings), progress=False, plots=False
    )
    assert again.tasks_run == 0 and again.tasks_skipped == 8
    assert len(result_rows(tmp_path / "ray")) == 8


def test_a_failing_ray_task_raises_its_error_here(local_ray: Any) -> None:
    def work(runner: Any, tasks: Any, recordings: Any) -> list[Any]:  # sent by value
        if recordings[0] == "bad":
            raise TaskError(f"episode {tasks[0].recording_path!r} failed: boom")
        return [(recordings[0],)]

    batches = [[SimpleNamespace(recording_path=p)] for p in ("good", "bad")]
    seen: list[Any] = []
    with pytest.raises(TaskError, match="episode 'bad' failed: boom"):
        run_on_ray(batches, None, 10, {}, work, lambda path: path, seen.append)
    assert seen in ([], ["good"]) and local_ray.is_initialized()  # the caller's Ray stays
