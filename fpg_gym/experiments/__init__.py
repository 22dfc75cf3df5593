"""Experiments: comparisons of methods on many episodes, the benchmarks and the demo.

The top of the library (only the command line is above it). A comparison is split by job:

=============  ================================================================================
``config``     what a comparison runs: :class:`EpisodeSpec`, :class:`CompareConfig`
``planning``   the episodes (clips x scenarios x seeds), keyed by content, simulated once
``run``        :func:`run_compare`: tasks (episode x method) in worker processes, resumable
``store``      the output folder: manifest, ``results.csv``, per-frame arrays
``stats``      :func:`summarise`: aggregates and the paired tests (``summary.json``)
``report``     the tables, ``report.md`` and the plots (:mod:`~fpg_gym.experiments.plots`)
=============  ================================================================================

:mod:`~fpg_gym.experiments.bench` (``fpg-gym bench``) and :mod:`~fpg_gym.experiments.demo`
(``fpg-gym demo``) are imported on their own (they are not re-exported here).
"""

from __future__ import annotations

from fpg_gym.experiments.config import CompareConfig, EpisodeSpec
from fpg_gym.experiments.planning import plan_episodes
from fpg_gym.experiments.report import (
    TABLE_COLUMNS,
    TEST_COLUMNS,
    format_table,
    format_tests,
    markdown_table,
    report_markdown,
    write_report,
)
from fpg_gym.experiments.run import CompareOutcome, run_compare
from fpg_gym.experiments.stats import summarise
from fpg_gym.experiments.store import CSV_FIELDS, MANIFEST_NAME

__all__ = [
    "CSV_FIELDS",
    "MANIFEST_NAME",
    "TABLE_COLUMNS",
    "TEST_COLUMNS",
    "CompareConfig",
    "CompareOutcome",
    "EpisodeSpec",
    "format_table",
    "format_tests",
    "markdown_table",
    "plan_episodes",
    "report_markdown",
    "run_compare",
    "summarise",
    "write_report",
]
