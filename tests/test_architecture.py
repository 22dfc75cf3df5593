"""The house rules of the code's structure (DESIGN.md, "Layout").

The layer contract itself is checked by import-linter (``lint-imports``, run by CI); these tests
pin what it does not: imports inside functions only for optional extras or a documented
start-up cost, and a bottom layer that loads nothing of the rest.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from fpg_gym.core.compiled import COMPILED_MODULES

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("fpg_gym", "optimizers", "policies")
#: Imported inside functions on purpose: optional extras, and heavy modules that only some
#: paths need (matplotlib ~0.5 s, scipy submodules, imageio, pybullet's own import).
LAZY_EXTERNALS = (
    "torch",
    "stable_baselines3",
    "cmaes",
    "ray",
    "numba",
    "rerun",
    "viser",
    "bvhio",
    "threadpoolctl",
    "matplotlib",
    "imageio",
    "scipy",
    "pybullet",
)
#: The command modules import the library in ``run()`` so that ``fpg-gym --help`` stays fast
#: (documented in :mod:`fpg_gym.commands`).
LAZY_MODULES = ("fpg_gym/commands/",)
#: The project's own modules that exist for an optional extra (and import it at their top, which
#: the last test checks): imported inside functions like the extra itself.
EXTRA_MODULES = dict.fromkeys(COMPILED_MODULES, "numba")


def _inner_imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text())
    top = {id(node) for node in tree.body}
    for node in tree.body:  # `if TYPE_CHECKING:` and `try:` blocks at module level are top level
        if isinstance(node, ast.If | ast.Try):
            top.update(id(child) for child in ast.walk(node))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in top:
            module = node.module if isinstance(node, ast.ImportFrom) else node.names[0].name
            found.append((node.lineno, module or ""))
    return found


def test_imports_inside_functions_are_only_optional_extras_or_heavy_modules() -> None:
    offenders = []
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            rel = path.relative_to(REPO).as_posix()
            if rel.startswith(LAZY_MODULES):
                continue
            for line, module in _inner_imports(path):
                if module.split(".")[0] not in LAZY_EXTERNALS and module not in EXTRA_MODULES:
                    offenders.append(f"{rel}:{line} imports {module} inside a function")
    assert not offenders, "\n".join(offenders)


def test_the_checker_sees_an_inner_import(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text("import os\n\ndef f():\n    import json\n    return json\n")
    assert _inner_imports(module) == [(4, "json")]


@pytest.mark.parametrize(
    ("module", "absent"),
    [
        ("optimizers", ("fpg_gym", "policies", "gymnasium", "torch", "pybullet", "scipy")),
        ("fpg_gym.reconstruct", ("torch", "matplotlib", "fpg_gym.env", "policies")),
        # The ragdoll is injected and the DeepMimic reader reads a table: no physics engine.
        ("fpg_gym.reconstruct", ("pybullet", "fpg_gym.physics", "fpg_gym.simulate")),
        ("fpg_gym.io", ("pybullet", "fpg_gym.physics")),
        ("fpg_gym.env", ("torch", "stable_baselines3", "matplotlib.pyplot", "fpg_gym.experiments")),
    ],
)
def test_a_layer_loads_nothing_above_it(module: str, absent: tuple[str, ...]) -> None:
    code = f"import sys, {module}\nprint(' '.join(m for m in {absent!r} if m in sys.modules))"
    loaded = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    ).stdout.split()
    assert loaded == [], f"import {module} loaded {loaded}"


@pytest.mark.parametrize(("module", "extra"), sorted(EXTRA_MODULES.items()))
def test_an_extra_module_imports_its_extra_at_its_top(module: str, extra: str) -> None:
    path = REPO / (module.replace(".", "/") + ".py")
    tree = ast.parse(path.read_text())
    top = [alias.name for node in tree.body if isinstance(node, ast.Import) for alias in node.names]
    assert extra in top, f"{module} should import {extra} at its top (it exists for that extra)"


def test_ci_runs_the_equation_tests_without_numba_too() -> None:
    """.ci/run runs the equation and kernel tests a second time with FPG_GYM_NO_NUMBA=1 (the
    numpy twins); every file it names exists, and the twins' own tests are among them."""
    script = (REPO / ".ci" / "run").read_text()
    command = script[script.index("FPG_GYM_NO_NUMBA=1") :].split("\n.venv/bin/ruff")[0]
    files = [word for word in command.split() if word.startswith("tests/")]
    assert all((REPO / name).is_file() for name in files), files
    for name in ("energy", "kernels", "reliability", "selection", "metrics", "poses", "filters"):
        assert f"tests/test_{name}.py" in files, name
