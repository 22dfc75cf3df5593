"""The optional extra of the torch samplers (``fpg-gym[learn]``: torch and stable-baselines3)."""

from __future__ import annotations

from typing import Any

from fpg_gym.core.errors import import_optional
from optimizers import MissingDependency

__all__ = ["INSTALL_HINT", "import_learn"]

#: What to install for learned samplers.
INSTALL_HINT = "pip install 'fpg-gym[learn]'"


def import_learn(module: str) -> Any:
    """Import ``module`` (``"torch"``, ``"stable_baselines3"``...) of the ``learn`` extra.

    Raises
    ------
    optimizers.MissingDependency
        When it is not installed; the message names ``pip install 'fpg-gym[learn]'``.
    """
    top = module.split(".")[0]
    return import_optional(
        module,
        MissingDependency(
            f"learned samplers need torch and stable-baselines3 ({top} is not installed): "
            f"{INSTALL_HINT}"
        ),
    )
