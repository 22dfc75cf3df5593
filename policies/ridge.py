"""The ridge fit of :mod:`fpg_gym.core.ridge` (one definition; kept here for the policies'
imports)."""

from fpg_gym.core.ridge import fit_ridge, predict_ridge, ridge_sums

__all__ = ["fit_ridge", "predict_ridge", "ridge_sums"]
