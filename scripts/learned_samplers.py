"""Train the learned samplers and compare them with the papers' search (issue 9 figures).

Two protocols, both with the held-out rule (samplers and graph never see an evaluated take):

* ``embedded``: the embedded DeepMimic clips. The default graph and the samplers use the 11
  clips other than walk, punch, kick, dance_b; those four are evaluated.
* ``bandai``: Bandai Namco dataset-1 split by whole takes (``scripts/holdout_split.py``, seed
  2016, 20 % held out). The graph and the samplers use the graph takes only; the first
  ``--eval-takes`` held-out takes (first ``--max-frames`` frames) are evaluated.

For each: ``fpg-gym train-sampler`` for the supervised and the PPO sampler (timed), then
``fpg-gym compare`` on the ``*-many`` scenarios with ``local-search`` (2,000 evaluations),
``learned:`` and ``learned+search:`` (200 each); then, on the same episodes (same seeds),
``random-search`` with 200 evaluations (the fair floor of a 200-evaluation sampler) and two
diagnostic rows run through the Python API: the sampler's anchor alone and its mean alone
(1 evaluation each). Prints one table per protocol (``table.md`` in each folder).

* ``uiprmd``: real Kinect v2 streams against Vicon, leave subjects out over s01-s08
  (:mod:`scripts.real_kinect`'s machinery: the UI-PRMD database and the Kinect v2 -> Vicon map
  of each fold are fitted on the other seven subjects only). The sampler learns the ground
  truth of the training subjects' real streams (every repetition; ``--train-reps N``: N per
  exercise); its imitation data of a training subject is collected with a database that lacks
  that subject too (nested), so the truth is never among the candidates, as on the held-out
  subject. ``--exclude-training LIST``: subjects no fold trains on (database, map, sampler),
  still scored when held out. ``--model linear`` (default): the linear pose-space sampler
  (:mod:`policies.pose_sampler`, target ``bones``), its settings chosen by leave-one-subject-out
  cross-validation over the seven training subjects, deterministic (one model per fold
  whatever ``--seeds``). ``--model mlp``: the supervised MLP (target ``truth``), one per
  training seed, one training subject per fold being the validation split (early stopping,
  spread calibration). Each model is scored on the held-out subject with ``learned:`` and
  ``learned+search:`` (200 evaluations) and its mean alone (1; a linear sampler's three with
  the output correction it learns from its own outputs of the training subjects,
  :mod:`policies.output_correction`, and ``uncorrected``: ``learned:`` without it;
  ``--no-correction``), beside ``closed-form`` (the
  anchor, 1), ``local-search`` (2,000), the raw sensor and two oracles that see the truth (its
  latent point by joints and by bones); 95 % confidence intervals by a bootstrap over episodes.
* ``sim``: the simulated held-out Bandai protocol (:mod:`sampler_study.sim`), the same models
  and rows.
* ``rl``: an RL sampler as a search accelerator (:mod:`sampler_study.rl`): PPO trained on the
  energy's gain without the closed form (:data:`sampler_study.rl.RL_ACCELERATOR`), then
  ``learned+search:`` (200 evaluations) against the local search at 2,000 and 200, the
  untrained policy and the zero action, paired per episode, on the embedded held-out clips
  (``--rl-model PATH``: evaluate that model instead of training one).

Usage::

    python scripts/learned_samplers.py --out runs/learned [--protocols embedded,bandai]
    python scripts/learned_samplers.py --protocols uiprmd --workers 2 --out runs/learned
    python scripts/learned_samplers.py --protocols sim --out runs/learned
    python scripts/learned_samplers.py --protocols rl --out runs/learned
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sampler_study import REPO, SCENARIOS
from sampler_study.compare import bandai_protocol, embedded_protocol
from sampler_study.rl import rl_protocol
from sampler_study.sim import sim_protocol
from sampler_study.uiprmd import report_finished, uiprmd_protocol

DATA = REPO.parent / "shared" / "data" / "bandai_namco"
#: Each protocol in the order a run takes them.
PROTOCOLS = {
    "sim": sim_protocol,
    "rl": rl_protocol,
    "uiprmd": uiprmd_protocol,
    "embedded": embedded_protocol,
    "bandai": bandai_protocol,
}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line (``args.argv``: its words, as a trained model records them)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "learned")
    parser.add_argument("--protocols", default="embedded,bandai")
    parser.add_argument("--data", type=Path, default=DATA, help="bandai_namco folder")
    parser.add_argument("--eval-takes", type=int, default=4)
    parser.add_argument("--max-frames", type=int, default=150)
    parser.add_argument("--sup-timesteps", type=int, default=20_000)
    parser.add_argument("--rl-timesteps", type=int, default=100_000)
    group = parser.add_argument_group("rl protocol")
    group.add_argument("--rl-model", default=None, help="evaluate this model (default: train one)")
    group.add_argument("--rl-seed", type=int, default=0, help="training seed (0)")
    group.add_argument(
        "--rl-eval-seeds", default="0,1,2", help="simulator seeds of the evaluated episodes"
    )
    group = parser.add_argument_group("uiprmd protocol")
    group.add_argument("--work", type=Path, default=Path("runs/real_kinect"), help="import folder")
    group.add_argument("--subjects", default="s01,s02,s03,s04,s05,s06,s07,s08")
    group.add_argument("--seeds", default="0,1,2", help="training seeds")
    group.add_argument("--reps", type=int, default=1, help="scored repetitions per exercise")
    group.add_argument(
        "--train-reps", type=int, default=0, help="training reps per exercise (0: all, default)"
    )
    group.add_argument(
        "--exclude-training",
        default="",
        metavar="LIST",
        help="subjects no fold trains on (database, sensor map, sampler), still scored when "
        "held out, e.g. s05 (its hip markers are flagged by import-uiprmd); default: none",
    )
    group.add_argument("--epochs", type=int, default=40)
    group.add_argument("--hidden", default="256,256", help="MLP layer widths")
    group.add_argument("--features", default="all", choices=("all", "latent"))
    group.add_argument(
        "--model",
        default="linear",
        choices=("linear", "mlp"),
        help="linear pose-space sampler (default) or the supervised MLP",
    )
    group.add_argument(
        "--correction",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the linear sampler learns an output correction from its own outputs of the "
        "training groups (default: yes; scored also without it, as 'uncorrected')",
    )
    group.add_argument("--uiprmd-thres1", type=float, default=0.1)
    group.add_argument("--sensor-blend", type=float, default=0.5)
    group.add_argument("--workers", type=int, default=1)
    group.add_argument(
        "--report-only", action="store_true", help="table of the finished folds in --out, no run"
    )
    group = parser.add_argument_group("sim protocol (also --seeds, --epochs, --hidden, --features)")
    group.add_argument("--sim-eval-takes", type=int, default=8, help="held-out takes scored")
    group.add_argument("--sim-train-frames", type=int, default=100, help="frames per stream")
    group.add_argument("--sim-train-scenarios", default=SCENARIOS)
    group.add_argument("--sim-val-share", type=float, default=0.1)
    group.add_argument(
        "--sim-folds", type=int, default=2, help="folds of the nested data collection (2)"
    )
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.report_only:  # the table of the folds a (possibly stopped) run has finished
        report_finished(args.out)
        return 0
    wanted = [p.strip() for p in args.protocols.split(",") if p.strip()]
    reports = [run(args) for name, run in PROTOCOLS.items() if name in wanted]
    (args.out / "tables.md").write_text("\n".join(reports))
    return 0


if __name__ == "__main__":
    sys.exit(main())
