"""``scripts/learned_samplers.py``'s table: seeds pooled and per seed, paired changes against
the closed-form anchor, bootstrap intervals."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def script() -> Any:
    sys.path.insert(0, str(REPO / "scripts"))  # it imports its neighbour real_kinect.py
    try:
        spec = importlib.util.spec_from_file_location(
            "learned_samplers", REPO / "scripts" / "learned_samplers.py"
        )
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(str(REPO / "scripts"))
    return module


def _rows(errors: dict[str, list[float]]) -> list[dict[str, Any]]:
    return [
        {"episode": f"e{i}", "method": method, "error": e, "jitter": 1.0, "cpu_ms": 1.0}
        for method, values in errors.items()
        for i, e in enumerate(values)
    ]


def test_table_pools_seeds_and_compares_with_the_anchor(script: Any) -> None:
    models = {"0": "/m/sampler_a_seed0", "1": "/m/sampler_a_seed1"}
    anchor = [0.10, 0.12, 0.08, 0.11]
    rows = _rows(
        {
            "raw": [0.2] * 4,
            "fpg:closed-form": anchor,
            "fpg:local-search": [0.1] * 4,
            f"fpg:learned:{models['0']}": [0.8 * e for e in anchor],
            f"fpg:learned:{models['1']}": [0.9 * e for e in anchor],
        }
    )
    table = script.uiprmd_table([{"subject": "s01", "models": models, "rows": rows}])
    lines = {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines()[2:]}
    assert set(lines) == {
        "raw", "closed-form", "local-search", "learned", "learned (seed 0)", "learned (seed 1)",
    }  # fmt: skip
    assert "-20.0 %" in lines["learned (seed 0)"] and "-10.0 %" in lines["learned (seed 1)"]
    assert "-15.0 %" in lines["learned"]  # the seeds pooled
    assert f"{np.mean(anchor) * 0.85:.4f}" in lines["learned"]


def test_subject_table_and_plot_take_each_fold_alone(script: Any, tmp_path: Path) -> None:
    models = {"0": "/m/sampler_a_seed0", "1": "/m/sampler_a_seed1"}
    folds = []
    for subject, factor in (("s02", 0.5), ("s01", 0.75)):
        anchor = [0.10, 0.12, 0.08]
        rows = _rows(
            {
                "fpg:closed-form": anchor,
                "fpg:local-search": [0.2] * 3,
                f"fpg:learned:{models['0']}": [factor * e for e in anchor],
                f"fpg:learned:{models['1']}": [factor * e for e in anchor],
            }
        )
        folds.append({"subject": subject, "models": models, "rows": rows})
    table = script.uiprmd_subject_table(folds)
    lines = table.splitlines()[2:]
    assert [line.split(" | ")[0].lstrip("| ") for line in lines] == ["s01", "s02"]
    assert "-25.0 %" in lines[0] and "-50.0 %" in lines[1]
    assert " | – | " in lines[0]  # no oracle-bones row in these folds
    path = script.plot_subjects(folds, tmp_path / "per_subject.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
