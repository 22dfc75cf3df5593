"""``fpg-gym train-sampler``: train a learned candidate sampler (supervised, RL or linear)."""

from __future__ import annotations

import argparse
import hashlib
from pathlib import Path
from typing import Any

from fpg_gym.commands import types
from fpg_gym.commands.compare import add_backend_arguments

NAME = "train-sampler"
HELP = (
    "train a learned candidate sampler (linear pose-space model, supervised torch MLP or "
    "stable-baselines3 PPO/SAC) for the optimisers learned:MODEL and learned+search:MODEL "
    "(the torch kinds need fpg-gym[learn])"
)

_EPILOG = """\
The model is written as MODEL.json (hyper-parameters, observation layout, training summary)
beside MODEL.pt (the network's weights: a torch state dict of tensors, loaded with
weights_only=True; no pickle), or for --kind linear MODEL.npz (arrays, allow_pickle=False);
checkpoints go to MODEL.checkpoints/. A supervised run stopped at any point (Ctrl-C, kill) goes
on where it stopped when the same command is run again: its collected episodes and its last
finished epoch are kept there (the same model as an uninterrupted run); --restart starts over.
Use it with
  fpg-gym compare --optimizers local-search,learned:MODEL,learned+search:MODEL ...

hold-out: train on the takes the graph is built from, never on evaluated takes. --graph default
(the embedded graph without the held-out clips walk, punch, kick, dance_b) trains on the other
embedded clips; --clips default means those. A seeded share of the clips (--val-share) is held
out for the periodic evaluation unless --val-clips is given. With --recordings, each training
group's data is collected with a graph and sensor map built from the other groups (as a new
subject's never contain it; --no-cross-fit: with --graph and --sensor-map), and --val-share 0
trains on every group.

examples:
  fpg-gym train-sampler --kind supervised --graph default --out runs/sampler_sup
  fpg-gym train-sampler --kind rl --algo ppo --graph default --timesteps 100000 \\
      --out runs/sampler_ppo
  fpg-gym train-sampler --kind supervised --graph runs/bandai.npz \\
      --clips @runs/split/graph_takes.txt --max-frames 150 --out runs/sampler_bandai
  fpg-gym train-sampler --kind supervised --target truth --follow anchor --graph default \\
      --out runs/sampler_truth       # learns the simulated ground truth, no search
  fpg-gym train-sampler --kind linear --target bones --follow anchor --graph default \\
      --out runs/sampler_linear      # the pose-space ridge sampler, numpy only, with its
                                     # learned output correction (--no-correction: without)
  fpg-gym train-sampler --kind linear --target bones --follow anchor --graph runs/vicon.npz \\
      --recordings runs/ui_prmd/recordings --group-pattern '_(s[0-9]+)_' \\
      --sensor-map runs/kinect.json --sensor-blend 0.5 --out runs/sampler_real
                                     # real paired data, subjects held out whole
                                     # (--val-share 0: train on every subject)

The samplers of docs/methods.md (ground truth of real UI-PRMD subjects, left out in turn, and of
simulated Bandai takes) come from
  python scripts/learned_samplers.py --protocols uiprmd,sim --seeds 0
and each model's JSON records the command that wrote it (training.command).
"""


def _list(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def _occlusion_cases(text: str) -> list[str]:
    """``--occlusions``: case names, or none for ``none``."""
    return [] if text.strip() == "none" else _list(text)


def _settings(text: str) -> dict[str, object]:
    """A JSON object of settings (``--hyperparameters``)."""
    import json

    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"not JSON ({error})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object, got {text!r}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Register the command's arguments."""
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.epilog = _EPILOG
    parser.add_argument(
        "--kind",
        choices=["supervised", "rl", "linear"],
        required=True,
        help="sampler kind (linear: the pose-space ridge model; needs --target bones or truth "
        "and learns the ground truth)",
    )
    parser.add_argument("--out", required=True, metavar="MODEL", help="model path (no suffix)")
    parser.add_argument("--seed", type=types.seed, default=0, help="seed (default 0)")
    _add_data_arguments(parser.add_argument_group("training data"))
    _add_recordings_arguments(parser.add_argument_group("paired recordings (--kind linear)"))
    _add_sensor_arguments(parser.add_argument_group("sensor"))
    _add_imitation_arguments(parser.add_argument_group("supervised and linear samplers"))
    _add_rl_arguments(parser.add_argument_group("RL samplers"))
    _add_model_arguments(parser.add_argument_group("model"))
    _add_run_arguments(parser.add_argument_group("run"))


def _add_data_arguments(group: Any) -> None:
    """What the sampler learns from and is evaluated on."""
    group.add_argument(
        "--graph",
        default="default",
        metavar="FILE",
        help="pose graph .npz, 'default' (embedded, without the held-out clips) or a packaged "
        "graph by name ('uiprmd')",
    )
    group.add_argument(
        "--clips",
        nargs="+",
        default=None,
        metavar="CLIP",
        help="training clips: mocap files/folders or embedded clip names; 'default' (the "
        "default) is the embedded clips of the default graph",
    )
    group.add_argument(
        "--val-clips",
        nargs="+",
        default=None,
        metavar="CLIP",
        help="clips for the periodic evaluation (default: a held-out share of --clips)",
    )
    group.add_argument(
        "--val-share",
        type=float,
        default=0.2,
        metavar="S",
        help="share of --clips (or of the --recordings' groups) held out for evaluation (0.2); "
        "with --recordings 0 trains on every group (settings by cross-validation over them, no "
        "final evaluation)",
    )
    group.add_argument(
        "--scenarios",
        type=_list,
        default=None,
        metavar="A,B",
        help="simulator scenarios (default front-many,left45-many,right45-many)",
    )
    group.add_argument(
        "--timesteps",
        type=types.integer(1),
        default=None,
        metavar="N",
        help="env steps (rl, default 100000) or training frames collected (supervised, "
        "default 20000)",
    )
    group.add_argument(
        "--max-frames",
        type=types.integer(2),
        default=None,
        metavar="N",
        help="first N frames per episode",
    )
    group.add_argument(
        "--no-mirror",
        action="store_true",
        help="do not add the mirror images of the training clips",
    )
    group.add_argument("--units", default="auto", help="BVH units (auto)")


def _add_recordings_arguments(group: Any) -> None:
    """Paired recordings instead of simulated clips (``--kind linear``)."""
    group.add_argument(
        "--recordings",
        nargs="+",
        default=None,
        metavar="PATH",
        help="--kind linear: learn from paired recordings (files, or folders of .npz: sensor "
        "streams with ground truth, e.g. fpg-gym import-uiprmd's) instead of simulated clips",
    )
    group.add_argument(
        "--group-pattern",
        default=None,
        metavar="REGEX",
        help="with --recordings: regular expression on the file names whose first group names "
        "a recording's group, e.g. '_(s[0-9]+)_' (UI-PRMD's subjects); groups are held out and "
        "cross-validated whole (default: each recording is its own group)",
    )
    group.add_argument(
        "--no-cross-fit",
        action="store_true",
        help="with --recordings: collect every group's data with --graph and --sensor-map "
        "(which contain it) instead of a graph and map built from the other training groups' "
        "recordings, as a new subject's are built without it (the default; --graph must then "
        "be the graph of these recordings' ground truth)",
    )
    group.add_argument(
        "--occlusions",
        type=_occlusion_cases,
        default=None,
        metavar="A,B",
        help="with --recordings: each training recording is also learnt from once with one of "
        "these occlusion cases put in, in turn (default: every case of the real-data occlusion "
        "benchmark, forearm,legs,hand-on-surface,side-turn; 'none': the recordings as they "
        "are); without them a sampler and its correction follow the sensor where it fails",
    )


def _add_sensor_arguments(group: Any) -> None:
    """The sensor map and blend of the training data and the evaluation."""
    group.add_argument(
        "--sensor-map",
        metavar="MAP.json",
        default=None,
        help="joint-definition map of the sensor (fpg-gym fit-map, or a packaged map by name) "
        "for the training data and "
        "the evaluation: give the one reconstruct --sensor-map will use",
    )
    group.add_argument(
        "--sensor-blend",
        type=float,
        default=0.0,
        metavar="F",
        help="the reconstructor's sensor blend for the training data and the evaluation (0): "
        "give the one reconstruct --sensor-blend will use",
    )


def _add_imitation_arguments(group: Any) -> None:
    """The targets and fit of the samplers that learn from imitation pairs."""
    group.add_argument(
        "--target",
        choices=["best", "search", "truth", "bones"],
        default="best",
        help="supervised target: the best search optimum (local search from x0 and from the "
        "anchor), the papers' local-search optimum, or the ground truth (truth: its joints "
        "projected; bones: its bone directions at the frame's bone lengths) (default best)",
    )
    group.add_argument(
        "--follow",
        choices=["search", "anchor", "truth"],
        default="search",
        help="what the supervised data's stream continues from: the local search (default), "
        "or, with --target truth or bones and no search at all, the closed-form anchor or the "
        "truth",
    )
    group.add_argument("--epochs", type=types.integer(1), default=40, help="supervised epochs (40)")
    group.add_argument(
        "--no-correction",
        action="store_true",
        help="--kind linear: no learned output correction (by default the sampler also learns "
        "a correction of the reconstructor's output from its own outputs of the training data, "
        "which learned: and learned+search: then apply)",
    )


def _add_rl_arguments(group: Any) -> None:
    """The RL algorithm and reward."""
    group.add_argument(
        "--algo", choices=["ppo", "sac"], default="ppo", help="RL algorithm (rl; default ppo)"
    )
    group.add_argument(
        "--reward",
        choices=["energy", "energy-gain", "error", "combined", "smooth"],
        default="energy",
        help="RL reward: the energy (default), its gain over the search's start x0 "
        "(log E(x0)/E), the simulated ground truth's error, "
        "energy + --error-weight x error, or error + --smooth-weight x the output's "
        "acceleration (m/s^2)",
    )
    group.add_argument(
        "--error-weight", type=float, default=1.0, help="error weight of --reward combined (1)"
    )
    group.add_argument(
        "--smooth-weight",
        type=float,
        default=0.002,
        help="acceleration weight of --reward smooth (0.002: 10 m/s^2 weighs as 2 cm of error)",
    )


def _add_model_arguments(group: Any) -> None:
    """The network, the observation layout and the action coordinates."""
    group.add_argument(
        "--hyperparameters",
        type=_settings,
        default=None,
        metavar="JSON",
        help="network and algorithm settings as a JSON object, e.g. "
        '\'{"learning_rate": 0.001, "gamma": 0}\' (rl: overrides policies.rl.RL_DEFAULTS; '
        "unknown keys are refused)",
    )
    group.add_argument("--k", type=types.integer(1), default=30, help="candidates per frame (30)")
    group.add_argument("--latent-dim", type=types.integer(1), default=20, help="latent axes (20)")
    group.add_argument(
        "--action-mode",
        choices=["absolute", "delta"],
        default="absolute",
        help="action coordinates of the sampler's Gaussian (default absolute)",
    )
    group.add_argument(
        "--action-scale", type=float, default=3.0, help="whitened units per action unit (3)"
    )
    group.add_argument(
        "--anchor",
        choices=["quadratic", "none"],
        default="quadratic",
        help="centre of the Gaussian: the closed-form minimiser of the energy's quadratic "
        "terms, or none (default quadratic)",
    )
    group.add_argument(
        "--features",
        default="all",
        metavar="SET",
        help="observation fields the model reads: 'all', 'latent' or a comma list",
    )


def _add_run_arguments(group: Any) -> None:
    """Evaluation, checkpoints, logs, workers and output."""
    group.add_argument(
        "--eval-every",
        type=types.integer(1),
        default=None,
        metavar="N",
        help="evaluate and checkpoint every N env steps (rl) or epochs (supervised)",
    )
    group.add_argument(
        "--eval-episodes",
        type=types.integer(1),
        default=6,
        metavar="N",
        help="held-out episodes (6)",
    )
    group.add_argument(
        "--tensorboard",
        default=None,
        metavar="DIR",
        help="TensorBoard log folder (only if tensorboard is installed)",
    )
    group.add_argument(
        "--workers",
        type=types.workers,
        default=1,
        metavar="N",
        help="processes (or Ray tasks) collecting the supervised data (1; the same data for any N)",
    )
    add_backend_arguments(group, "where the supervised data is collected: local processes")
    group.add_argument(
        "--restart",
        action="store_true",
        help="supervised: start over instead of going on from MODEL.checkpoints/ (removes its "
        "data and fit checkpoints)",
    )
    group.add_argument("--quiet", action="store_true", help="no progress bars")
    group.add_argument(
        "--json",
        action="store_true",
        help="print a JSON summary last (the clips and recordings as counts, folders and a hash)",
    )


#: Inputs listed in ``--json``'s config as a summary (a shell glob can give thousands).
LISTED_INPUTS: tuple[str, ...] = ("clips", "val_clips", "recordings")
#: A list of inputs this short is kept whole in the summary.
MAX_LISTED = 10


def input_summary(items: list[str] | None) -> dict[str, Any] | None:
    """A list of inputs in a few fields: ``count``, ``folders`` (those of the items that name
    existing files or folders), ``sha256`` (of the items as given, one per line) and, for at
    most :data:`MAX_LISTED` items, ``items``."""
    if items is None:
        return None
    names = [str(item) for item in items]
    folders = sorted({str(Path(n).parent) for n in names if Path(n).is_file()})
    folders += sorted({n for n in names if Path(n).is_dir()} - set(folders))
    summary: dict[str, Any] = {
        "count": len(names),
        "folders": folders,
        "sha256": hashlib.sha256("\n".join(names).encode("utf-8")).hexdigest(),
    }
    if len(names) <= MAX_LISTED:
        summary["items"] = names
    return summary


def run(args: argparse.Namespace) -> int:
    """Train, save and print the final evaluation."""
    from fpg_gym.commands.output import emit_json
    from fpg_gym.core.outputs import check_output
    from fpg_gym.definitions import packaged_map_names
    from fpg_gym.graph import GRAPH_NAMES
    from policies.pose_sampler import LINEAR_WEIGHTS_SUFFIX
    from policies.sampler import FEATURE_SETS, WEIGHTS_SUFFIX, model_paths
    from policies.training import TrainConfig, config_dict, train_sampler

    # Before any work: MODEL.json and MODEL.pt must not be inputs, folders or unwritable.
    inputs = [
        item
        for item in [
            args.graph,
            args.sensor_map,
            *(args.clips or []),
            *(args.val_clips or []),
            *(args.recordings or []),
        ]
        if item
    ]
    # Graphs and maps by name (--graph uiprmd, --sensor-map kinect-v2-to-vicon) are no files.
    names = {*GRAPH_NAMES, *packaged_map_names()}
    json_path, stem = model_paths(args.out)
    suffix = LINEAR_WEIGHTS_SUFFIX if args.kind == "linear" else WEIGHTS_SUFFIX
    for target in (json_path, stem.with_name(stem.name + suffix)):
        check_output(target, [i for i in inputs if i not in names])

    features = (
        list(FEATURE_SETS[args.features]) if args.features in FEATURE_SETS else _list(args.features)
    )
    if args.occlusions is not None and not args.recordings:
        raise ValueError("--occlusions: only with --recordings (simulated clips take --scenarios)")
    config = TrainConfig(
        kind=args.kind,
        out=args.out,
        algo=args.algo,
        graph=args.graph,
        clips=args.clips,
        val_clips=args.val_clips,
        val_share=args.val_share,
        scenarios=args.scenarios,
        timesteps=args.timesteps,
        seed=args.seed,
        target=args.target,
        follow=args.follow,
        reward=args.reward,
        error_weight=args.error_weight,
        smooth_weight=args.smooth_weight,
        epochs=args.epochs,
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        max_frames=args.max_frames,
        k=args.k,
        latent_dim=args.latent_dim,
        action_scale=args.action_scale,
        action_mode=args.action_mode,
        anchor=args.anchor,
        features=features,
        hyperparameters=dict(args.hyperparameters or {}),
        mirror=not args.no_mirror,
        tensorboard=args.tensorboard,
        units=args.units,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        progress=not args.quiet,
        restart=args.restart,
        recordings=args.recordings,
        group_pattern=args.group_pattern,
        sensor_map=args.sensor_map,
        sensor_blend=args.sensor_blend,
        correction=not args.no_correction,
        cross_fit=not args.no_cross_fit,
        **({} if args.occlusions is None else {"occlusions": args.occlusions}),
    )
    result = train_sampler(config)
    if args.json:
        settings = config_dict(config)
        settings.update({name: input_summary(settings[name]) for name in LISTED_INPUTS})
        emit_json(
            {
                "model": result.model,
                "config": settings,
                "seconds": result.seconds,
                "evaluation": result.evaluation,
            }
        )
    return 0
