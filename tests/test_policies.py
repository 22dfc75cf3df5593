"""Learned candidate samplers: features and anchor, supervised and RL training, files, the
``learned:PATH`` optimisers, method names, the optional-extra errors and the CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import optimizers
from fpg_gym.env import KinectPoseEnv
from fpg_gym.env_observation import CONTEXT_NAMES, LATENT_LIMIT
from fpg_gym.io import load_default_clips
from policies.loading import load_sampler
from policies.sampler import (
    AnchorSampler,
    FeatureMap,
    SamplerSpec,
    problem_observation,
)
from policies.training import collect_imitation_data, simulate_episodes

pytest.importorskip("torch")

SMALL = {"k": 8, "latent_dim": 7}
EPISODE = {"clip": "run", "scenario": "front-many", "seed": 1}


def make_env(graph: Any, **kwargs: Any) -> KinectPoseEnv:
    options: dict[str, Any] = {
        **SMALL,
        "clips": ("run",),
        "scenarios": ("front-many",),
        "ragdoll": False,
        "action_mode": "absolute",
        "clip_actions": False,
    }
    options.update(kwargs)
    return KinectPoseEnv(graph, **options)


def small_spec(env: KinectPoseEnv, kind: str = "supervised", **kwargs: Any) -> SamplerSpec:
    return SamplerSpec.for_env(env, kind, "mlp" if kind == "supervised" else "ppo", **kwargs)


@pytest.fixture(scope="module")
def trained(graph: Any, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A small supervised sampler trained on two simulated episodes, saved."""
    from policies.supervised import SupervisedSampler
    from policies.supervised_fit import fit_supervised

    env = make_env(graph)
    spec = small_spec(env, hyperparameters={"hidden": [32, 32]})
    env.close()
    clip = load_default_clips(["run"])
    recordings = simulate_episodes(clip, ["front-many"], [0, 1])
    data = collect_imitation_data(graph, recordings, spec, target="best", seed=0)
    features = spec.feature_map()(data.observations)
    sampler = SupervisedSampler.create(
        spec, features.mean(axis=0), np.maximum(features.std(axis=0), 1e-3), seed=0
    )
    history = fit_supervised(
        sampler, data.observations, data.actions, data.masks, epochs=60, batch_size=16, seed=0
    )
    path = tmp_path_factory.mktemp("models") / "sampler"
    sampler.save(path)
    return {"sampler": sampler, "history": history, "data": data, "path": path, "spec": spec}


# --------------------------------------------------------------------------- features


def test_problem_observation_gives_the_env_features(graph: Any) -> None:
    env = make_env(graph)
    spec = small_spec(env)
    feature_map = spec.feature_map()
    obs, _ = env.reset(seed=0, options=EPISODE)
    for _ in range(4):
        problem = env.unwrapped.problem
        rebuilt = problem_observation(
            problem, feature_map.layout, action_scale=spec.action_scale, delta=False
        )
        context = env.unwrapped.layout.slices["context"]
        differs = np.flatnonzero(obs != rebuilt)
        masked = {context.start + CONTEXT_NAMES.index(n) for n in ("no_body", "progress")}
        assert set(differs.tolist()) <= masked  # only what a problem cannot know
        np.testing.assert_array_equal(feature_map(obs), feature_map(rebuilt))
        obs, *_ = env.step(np.zeros(env.action_space.shape))
    env.close()


def test_quadratic_anchor_minimises_the_quadratic_energy(graph: Any) -> None:
    env = make_env(graph)
    spec = small_spec(env)
    env.reset(seed=0, options=EPISODE)
    for _ in range(3):  # later frames have a prediction (the motion term)
        env.step(np.zeros(env.action_space.shape))
    problem = env.unwrapped.problem
    assert problem.prediction is not None
    _, _, anchor = AnchorSampler(spec).latent_gaussian(problem)
    assert anchor is not None and np.all(np.abs(anchor) < LATENT_LIMIT * spec.action_scale)
    w_c, w_s, _, w_m = spec.energy_weights

    def quadratic(z: np.ndarray) -> np.ndarray:
        terms = problem.evaluate_terms(z, count=False)
        ridge = w_s / 20 * spec.anchor_style * np.sum((z * problem.std) ** 2, axis=1)
        return w_c * terms["Ec"] + w_m * terms["Em"] + ridge + 1e-5 * np.sum(z**2, axis=1)

    rng = np.random.default_rng(0)
    around = anchor + 0.05 * rng.standard_normal((64, problem.dim))
    assert np.all(quadratic(around) > quadratic(anchor[None])[0])
    assert problem.evaluations == 0
    env.close()


def test_feature_map_rejects_another_layout(graph: Any) -> None:
    env = make_env(graph)
    feature_map = small_spec(env).feature_map()
    with pytest.raises(ValueError, match="expected shape"):
        feature_map(np.zeros(feature_map.layout.size + 1, np.float32))
    with pytest.raises(ValueError, match="unknown observation field"):
        FeatureMap(feature_map.layout, ["kinect", "no_such_field"])
    env.close()


# --------------------------------------------------------------------------- supervised


def test_supervised_training_lowers_the_loss_and_round_trips(trained: dict[str, Any]) -> None:
    history = trained["history"]
    assert history[-1]["train_loss"] < history[0]["train_loss"] - 0.5
    sampler, data = trained["sampler"], trained["data"]
    # The learned mean is closer to the targets than the anchor alone (pose-weighted).
    mean, _, anchor = sampler.distribution(data.observations)
    spread = sampler.layout.split(data.observations)["latent_std"] ** 2 * data.masks
    learned = np.sum(spread * (data.actions - mean) ** 2)
    alone = np.sum(spread * (data.actions - anchor) ** 2)
    assert learned < alone  # (over several seeds: the next test)
    loaded = load_sampler(trained["path"])
    assert type(loaded) is type(sampler) and loaded.spec.to_json() == sampler.spec.to_json()
    obs = data.observations[:10]
    np.testing.assert_array_equal(loaded.predict(obs)[0], sampler.predict(obs)[0])
    np.testing.assert_array_equal(loaded.gaussian(obs)[1], sampler.gaussian(obs)[1])
    # Tensors only: the weights load with torch's safe loader.
    import torch

    state = torch.load(Path(f"{trained['path']}.pt"), weights_only=True)
    assert all(isinstance(v, torch.Tensor) for v in state.values())
    description = json.loads(Path(f"{trained['path']}.json").read_text())
    assert description["observation_size"] == sampler.layout.size
    assert description["observation_fields"][0]["name"] == "kinect"


def test_supervised_learning_beats_the_anchor_over_seeds(trained: dict[str, Any]) -> None:
    """A statement over seeds, not one seed: every training gets its mean closer to the targets
    than the anchor alone, and on average by at least a quarter (pose-weighted squared error)."""
    from policies.supervised import SupervisedSampler
    from policies.supervised_fit import fit_supervised

    data, spec = trained["data"], trained["spec"]
    features = spec.feature_map()(data.observations)
    spread = (
        SupervisedSampler.create(
            spec, features.mean(axis=0), np.maximum(features.std(axis=0), 1e-3), seed=0
        ).layout.split(data.observations)["latent_std"]
        ** 2
        * data.masks
    )
    ratios = []
    for seed in range(4):
        sampler = SupervisedSampler.create(
            spec, features.mean(axis=0), np.maximum(features.std(axis=0), 1e-3), seed=seed
        )
        fit_supervised(
            sampler, data.observations, data.actions, data.masks, epochs=60, batch_size=16,
            seed=seed,
        )  # fmt: skip
        mean, _, anchor = sampler.distribution(data.observations)
        learned = np.sum(spread * (data.actions - mean) ** 2)
        ratios.append(learned / np.sum(spread * (data.actions - anchor) ** 2))
    # Why these bounds: over training seeds 0-7 (60 epochs, measured on the shared 2-core box,
    # with the per-episode generators of the imitation data) the ratio is 0.50-0.66, mean 0.57,
    # standard deviation 0.06; a mean of four seeds then has a standard error of about 0.03, so
    # 0.75 is 6 standard errors above it; 1.0 (no better than the anchor) is 7 standard
    # deviations above the mean of single seeds.
    assert max(ratios) < 1.0 and np.mean(ratios) < 0.75, ratios


def test_validation_shrinks_an_offset_that_does_not_carry_over(
    trained: dict[str, Any], tmp_path: Path
) -> None:
    """``mean_scale``: 0 when the validation targets are the anchor itself (the sampler falls
    back to it), near 1 when they are the training targets; files without it still load."""
    import torch

    from policies.supervised import SupervisedSampler
    from policies.supervised_fit import fit_supervised

    data, spec = trained["data"], trained["spec"]
    features = spec.feature_map()(data.observations)
    scales = {}
    for name in ("anchor", "training"):
        sampler = SupervisedSampler.create(
            spec, features.mean(axis=0), np.maximum(features.std(axis=0), 1e-3), seed=0
        )
        _, _, anchor = sampler.distribution(data.observations)
        targets = anchor if name == "anchor" else data.actions
        history = fit_supervised(
            sampler, data.observations, data.actions, data.masks, epochs=30, batch_size=16,
            validation=(data.observations, targets, data.masks), restore_best=False,
        )  # fmt: skip
        scales[name] = history[-1]["mean_scale"]
        if name == "anchor":
            mean, _, anchor = sampler.distribution(data.observations)
            np.testing.assert_allclose(mean, anchor, atol=1e-6)
    assert scales["anchor"] < 0.05 < 0.7 < scales["training"] <= 1.0, scales
    # A file written before mean_scale existed loads with a scale of 1.
    sampler = trained["sampler"]
    path = sampler.save(tmp_path / "old")
    weights = tmp_path / "old.pt"
    state = torch.load(weights, weights_only=True)
    state.pop("mean_scale")
    torch.save(state, weights)
    loaded = load_sampler(path)
    assert float(loaded.module.mean_scale) == 1.0


def test_supervised_training_is_deterministic(trained: dict[str, Any]) -> None:
    from policies.supervised import SupervisedSampler
    from policies.supervised_fit import fit_supervised

    data, spec = trained["data"], trained["spec"]
    features = spec.feature_map()(data.observations)
    runs = []
    for _ in range(2):
        sampler = SupervisedSampler.create(
            spec, features.mean(axis=0), np.maximum(features.std(axis=0), 1e-3), seed=0
        )
        fit_supervised(
            sampler, data.observations, data.actions, data.masks, epochs=3, batch_size=16
        )
        runs.append(sampler.predict(data.observations[:5])[0])
    np.testing.assert_array_equal(runs[0], runs[1])


def test_a_sampler_refuses_another_observation_size(graph: Any, trained: dict[str, Any]) -> None:
    sampler = trained["sampler"]
    other = make_env(graph, k=10, latent_dim=9)
    with pytest.raises(ValueError, match="observations of size"):
        load_sampler(trained["path"], env=other)
    same = make_env(graph, clip_actions=True)
    with pytest.warns(UserWarning, match="clip_actions=False"):
        load_sampler(trained["path"], env=same)
    same.close()
    obs, _ = other.reset(seed=0, options=EPISODE)
    with pytest.raises(ValueError, match="expected shape"):
        sampler.predict(obs)
    with pytest.raises(ValueError, match="does not fit"):
        sampler.observe(other.unwrapped.problem)
    other.close()


def test_loading_checks_the_files(tmp_path: Path, trained: dict[str, Any]) -> None:
    with pytest.raises(FileNotFoundError, match="no sampler description"):
        load_sampler(tmp_path / "missing")
    (tmp_path / "bad.json").write_text(json.dumps({"format": "something else"}))
    with pytest.raises(ValueError, match="not an fpg-gym sampler"):
        load_sampler(tmp_path / "bad")
    spec = json.loads(Path(f"{trained['path']}.json").read_text())
    (tmp_path / "orphan.json").write_text(json.dumps(spec))
    with pytest.raises(FileNotFoundError, match="weights file"):
        load_sampler(tmp_path / "orphan.json")


# --------------------------------------------------------------------------- optimisers


def test_learned_optimisers_spend_their_budget_deterministically(
    graph: Any, trained: dict[str, Any]
) -> None:
    path = str(trained["path"])
    env = make_env(graph)
    env.reset(seed=0, options=EPISODE)
    problem = env.unwrapped.problem
    learned = optimizers.make(f"learned:{path}")
    found = optimizers.run_optimizer(problem, learned, rng=3)
    assert problem.evaluations == 200
    mean, _, anchor = trained["sampler"].latent_gaussian(problem)
    firsts = problem.evaluate_terms(np.stack([mean, anchor]), count=False)["E"]
    assert found.energy <= firsts.min()
    env.reset(seed=0, options=EPISODE)
    again = optimizers.run_optimizer(env.unwrapped.problem, learned, rng=3)
    np.testing.assert_array_equal(found.x, again.x)
    env.reset(seed=0, options=EPISODE)
    search = optimizers.make(f"learned+search:{path}", samples=20, search_samples=10)
    optimizers.run_optimizer(env.unwrapped.problem, search, rng=0)
    assert env.unwrapped.problem.evaluations == 40
    env.close()
    tight = make_env(graph, max_evaluations=50)  # the env's budget rules
    tight.reset(seed=0, options=EPISODE)
    tight.unwrapped.reconstructor.search(f"learned+search:{path}", rng=0)
    assert tight.unwrapped.problem.evaluations == 50
    tight.close()


def test_learned_samplers_run_episodes_as_optimisers_and_policies(
    graph: Any, trained: dict[str, Any]
) -> None:
    from fpg_gym.episodes import run_episode

    env = make_env(graph, reward_mode="error")
    searched = run_episode(env, f"learned:{trained['path']}", seed=0, options=EPISODE)
    assert np.all(searched.evaluations == 200)
    acting = run_episode(env, trained["sampler"], seed=0, options=EPISODE)
    assert np.all(acting.evaluations == 0) and acting.steps == searched.steps
    assert np.mean(searched.energies) <= np.mean(acting.energies)
    env.close()


def test_method_names_carry_learned_optimisers() -> None:
    from fpg_gym.methods import parse_method

    method = parse_method("fpg:learned+search:/tmp/a+b/model+ragdoll")
    assert method.optimizer == "learned+search:/tmp/a+b/model" and method.ragdoll
    assert parse_method(method.name) == method
    assert parse_method("shum:learned:runs/m").optimizer == "learned:runs/m"
    with pytest.raises(ValueError, match="suffix"):
        parse_method("fpg+physics")
    with pytest.raises(ValueError, match="suffix"):
        parse_method("holt:smoothed+fast")
    with pytest.raises(optimizers.OptimizerNotFound, match="learned:ARG"):
        optimizers.make("unknown:thing")


def test_registry_prefix_factories() -> None:
    calls: list[tuple[str, dict[str, Any]]] = []

    def factory(argument: str, **kwargs: Any) -> Any:
        calls.append((argument, kwargs))
        return optimizers.make("none")

    optimizers.register_prefix("toy-prefix", factory, overwrite=True)
    assert "toy-prefix" in optimizers.prefixes() and "learned" in optimizers.prefixes()
    optimizers.make("toy-prefix:a:b", x=1)
    assert calls == [("a:b", {"x": 1})]
    with pytest.raises(ValueError, match="already registered"):
        optimizers.register_prefix("learned", factory)


def test_compare_runs_learned_samplers(tmp_path: Path, trained: dict[str, Any]) -> None:
    from fpg_gym.experiments import CompareConfig, run_compare

    path = trained["path"]
    config = CompareConfig(
        out=str(tmp_path / "cmp"),
        methods=[f"fpg:learned:{path}", f"fpg:learned+search:{path}"],
        clips=["walk"],
        scenarios=["front-many"],
        max_frames=6,
        k=8,
        baseline=f"fpg:learned:{path}",
    )
    run_compare(config, progress=False, plots=False, log=lambda _: None)
    text = (tmp_path / "cmp" / "results.csv").read_text()
    assert f"fpg:learned+search:{path}" in text and f"fpg:learned:{path}" in text
    lines = text.strip().splitlines()
    assert len(lines) == 3  # header + one row per method
    header = lines[0].split(",")
    for line in lines[1:]:
        row = dict(zip(header, line.split(","), strict=True))
        assert float(row["evaluations_mean"]) <= 200 and float(row["mean_error_m"]) > 0


# --------------------------------------------------------------------------- RL


def test_rl_training_improves_the_return_and_round_trips(graph: Any, tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3")
    from fpg_gym.episodes import run_episode
    from policies.rl import make_training_env, train_rl

    clips = load_default_clips(["run"])
    env = make_training_env(graph, clips, ["front-many"], action_mode="absolute", **SMALL)

    def evaluate(sampler: Any) -> dict[str, Any]:
        rewards = []
        for seed in (0, 1):  # the same episodes and draws every time
            sampler.rng = np.random.default_rng(seed)
            result = run_episode(env, sampler, seed=seed, deterministic=False)
            rewards.append(np.mean(result.rewards))
        return {"mean": {"mean_energy": -float(np.mean(rewards)), "mean_error": 0.0}}

    sampler, history = train_rl(
        graph=graph,
        clips=clips,
        scenarios=["front-many"],
        timesteps=1536,
        seed=0,
        action_mode="absolute",
        hyperparameters={
            "n_steps": 256,
            "batch_size": 64,
            "n_epochs": 10,
            "learning_rate": 3e-3,
            "net_arch": [32, 32],
            "log_std_init": 0.0,
            "gamma": 0.0,
        },
        evaluate=evaluate,
        eval_every=1536,
        **SMALL,
    )
    energies = [r["eval_mean_energy"] for r in history if "eval_mean_energy" in r]
    # Not a seed-tuned bound: with training seeds 0-5 the last evaluation's energy is 0.46-0.63
    # of the first (measured on the shared 2-core box), so "lower" holds with a wide margin.
    assert len(energies) == 2 and energies[-1] < energies[0]
    assert any("reward_per_step" in r for r in history)
    path = sampler.save(tmp_path / "ppo")
    loaded = load_sampler(path)
    obs, _ = env.reset(seed=3)
    np.testing.assert_array_equal(loaded.predict(obs)[0], sampler.predict(obs)[0])
    np.testing.assert_array_equal(loaded.gaussian(obs)[1], sampler.gaussian(obs)[1])
    env.close()


def test_rl_evaluations_score_the_policy_between_updates(graph: Any, tmp_path: Path) -> None:
    """Issue 35: the last periodic evaluation is of the policy the run returns (PPO updates
    after each rollout; an evaluation during one scored a policy the run then changed), and the
    untrained policy is kept as the step-0 checkpoint; the zero action's mean is zero."""
    pytest.importorskip("stable_baselines3")
    from policies.rl import UNTRAINED_CHECKPOINT, make_training_env, train_rl, zero_action

    clips = load_default_clips(["run"])
    env = make_training_env(graph, clips, ["front-many"], action_mode="absolute", **SMALL)
    obs, _ = env.reset(seed=3)
    seen: list[float] = []

    def evaluate(sampler: Any) -> dict[str, Any]:
        mean = float(np.abs(sampler.gaussian(obs)[0]).sum())  # what the weights say here
        seen.append(mean)
        return {"mean": {"mean_energy": mean, "mean_error": mean}}

    sampler, history = train_rl(
        graph=graph,
        clips=clips,
        scenarios=["front-many"],
        timesteps=300,  # three rollouts of 128 steps: 384 steps, updates at 128, 256, 384
        seed=0,
        action_mode="absolute",
        hyperparameters={"n_steps": 128, "batch_size": 64, "n_epochs": 2, "net_arch": [16]},
        evaluate=evaluate,
        eval_every=200,
        checkpoints=tmp_path / "checkpoints",
        **SMALL,
    )
    steps = [r["timesteps"] for r in history if "eval_mean_error" in r]
    assert steps == [0, 256, 384]  # at step 0, after the update that passed 200, at the end
    assert history[-1]["eval_mean_error"] == evaluate(sampler)["mean"]["mean_error"]
    assert len(set(seen[:3])) == 3  # each evaluation saw other weights
    untrained = load_sampler(tmp_path / "checkpoints" / UNTRAINED_CHECKPOINT)
    assert float(np.abs(untrained.gaussian(obs)[0]).sum()) == seen[0]
    zero = zero_action(sampler)
    mean, std = zero.gaussian_features(zero.features(obs[None]))  # relative to the anchor
    np.testing.assert_array_equal(mean, 0.0)
    np.testing.assert_allclose(std[0], sampler.gaussian(obs)[1])
    env.close()


def test_rl_training_env_takes_the_error_reward(graph: Any) -> None:
    """``--reward error``: the RL sampler's env rewards minus the ground truth's error."""
    from policies.rl import make_training_env

    clips = load_default_clips(["run"])
    env = make_training_env(
        graph, clips, ["front-many"], action_mode="absolute", reward_mode="error", **SMALL
    )
    try:
        env.reset(seed=0)
        for _ in range(3):
            _, reward, _, _, info = env.step(np.zeros(env.action_space.shape))
            assert reward == pytest.approx(-info["frame_error"]) and info["frame_error"] > 0
    finally:
        env.close()


def test_rl_training_env_takes_the_energy_gain_reward(graph: Any) -> None:
    """``--reward energy-gain``: log(E(x0) / E(z)), positive where the point beats the
    search's start."""
    from policies.rl import make_training_env

    clips = load_default_clips(["run"])
    env = make_training_env(
        graph, clips, ["front-many"], action_mode="delta", reward_mode="energy-gain", **SMALL
    )
    try:
        env.reset(seed=0)
        for _ in range(3):
            _, reward, _, _, info = env.step(np.zeros(env.action_space.shape))  # x0 itself
            assert reward == pytest.approx(np.log(info["energy_x0"] / info["energy"]))
            assert reward == pytest.approx(0.0, abs=1e-9)
        _, reward, _, _, info = env.step(np.full(env.action_space.shape, 2.0))  # far off
        assert reward < 0 and info["energy"] > info["energy_x0"]
    finally:
        env.close()
    with pytest.raises(ValueError, match="reward_mode"):
        make_training_env(graph, clips, ["front-many"], reward_mode="gain", **SMALL)


def test_rl_training_env_takes_the_smooth_reward(graph: Any) -> None:
    """``--reward smooth``: minus the error and ``smooth_weight`` x the output's acceleration,
    the second difference of the last three outputs over their timestamps (by hand)."""
    from policies.rl import make_training_env

    clips = load_default_clips(["run"])
    env = make_training_env(
        graph,
        clips,
        ["front-many"],
        action_mode="absolute",
        reward_mode="smooth",
        smooth_weight=0.01,
        **SMALL,
    )
    try:
        env.reset(seed=0)
        outputs = []
        for step in range(4):
            _, reward, _, _, info = env.step(np.zeros(env.action_space.shape))
            outputs.append((info["pose"].astype(np.float64), info["timestamp"]))
            if step < 2:  # no acceleration before three outputs
                assert info["acceleration"] == 0.0
                assert reward == pytest.approx(-info["frame_error"])
                continue
            (p0, t0), (p1, t1), (p2, t2) = outputs[-3:]
            second = 2.0 * ((p2 - p1) / (t2 - t1) - (p1 - p0) / (t1 - t0)) / (t2 - t0)
            expected = float(np.linalg.norm(second, axis=1).mean())
            assert info["acceleration"] == pytest.approx(expected, rel=1e-6) and expected > 0
            assert reward == pytest.approx(-(info["frame_error"] + 0.01 * expected))
        with pytest.raises(ValueError, match="smooth_weight"):
            make_training_env(graph, clips, ["front-many"], reward_mode="smooth", smooth_weight=-1)
    finally:
        env.close()


# --------------------------------------------------------------------------- extra, CLI


def test_imports_need_neither_torch_nor_sb3() -> None:
    code = (
        "import sys; sys.modules['torch'] = None; sys.modules['stable_baselines3'] = None\n"
        "import fpg_gym, optimizers, policies, policies.sampler, policies.training\n"
        "import policies.learned_optimizers, fpg_gym.commands.train_sampler\n"
        "from fpg_gym.cli import build_parser; build_parser()\n"
        "print('imported')"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert "imported" in out.stdout


def test_missing_extra_names_the_install_command(
    monkeypatch: pytest.MonkeyPatch, trained: dict[str, Any], tmp_path: Path
) -> None:
    from policies.training import TrainConfig, train_sampler

    hint = r"pip install 'fpg-gym\[learn\]'"
    torch = sys.modules["torch"]
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(optimizers.MissingDependency, match=hint):
        load_sampler(trained["path"])
    with pytest.raises(optimizers.MissingDependency, match=hint):
        optimizers.make(f"learned:{trained['path']}")
    monkeypatch.setitem(sys.modules, "torch", torch)
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)
    with pytest.raises(optimizers.MissingDependency, match=hint):
        train_sampler(TrainConfig(kind="rl", out=str(tmp_path / "m")))


def test_cli_trains_a_tiny_supervised_sampler(tmp_path: Path, capsys: Any) -> None:
    from fpg_gym.cli import main

    out = tmp_path / "cli_model"
    code = main(
        [
            "train-sampler",
            "--kind", "supervised",
            "--clips", "run",
            "--val-clips", "jump",
            "--scenarios", "front-many",
            "--timesteps", "12",
            "--epochs", "2",
            "--k", "8",
            "--latent-dim", "7",
            "--max-frames", "6",
            "--eval-episodes", "1",
            "--no-mirror",
            "--out", str(out),
            "--quiet",
            "--json",
        ]
    )  # fmt: skip
    assert code == 0
    assert Path(f"{out}.json").is_file() and Path(f"{out}.pt").is_file()
    checkpoints = sorted(p.name for p in Path(f"{out}.checkpoints").iterdir())
    # The evaluated samplers; what a stopped run goes on from is removed once the model is
    # written (tests/test_resume.py).
    assert checkpoints == [f"epoch-000{e}.{x}" for e in (1, 2) for x in ("json", "pt")]
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert {"learned (200)", "local-search (2000)"} <= set(summary["evaluation"])
    assert load_sampler(out).spec.training["frames"] == 12


def test_cli_trains_a_tiny_rl_sampler_and_evaluates_it(tmp_path: Path) -> None:
    """The whole RL command, final evaluation included: its learned optimisers are copied per
    evaluated stream, and a trained SB3 policy cannot be deep-copied (it is shared)."""
    from fpg_gym.cli import main

    out = tmp_path / "rl_model"
    code = main(
        [
            "train-sampler", "--kind", "rl", "--clips", "run", "--val-clips", "jump",
            "--scenarios", "front-many", "--timesteps", "64", "--k", "8", "--latent-dim", "7",
            "--max-frames", "6", "--eval-episodes", "1", "--no-mirror", "--quiet",
            "--reward", "smooth", "--out", str(out),
        ]
    )  # fmt: skip
    assert code == 0
    sampler = load_sampler(out)
    assert sampler.spec.training["smooth_weight"] == 0.002
    evaluation = sampler.spec.training["evaluation"]
    assert {"learned (200)", "learned+search (200)"} <= set(evaluation)
    assert all(np.isfinite(row["jitter"]) for row in evaluation.values())
    for row in evaluation.values():  # one episode: the interval is the mean itself
        assert row["error_ci_low"] == pytest.approx(row["mean_error"])
        assert row["error_ci_high"] == pytest.approx(row["mean_error"])


def test_learned_optimiser_copies_share_the_model(trained: dict[str, Any]) -> None:
    import copy

    from policies.learned_optimizers import LearnedSearch

    search = LearnedSearch(trained["sampler"])
    twin = copy.deepcopy(search)
    assert twin.sampler is search.sampler and twin is not search
    twin.samples = 7
    assert search.samples != 7


def test_cli_trains_on_the_ground_truth_without_search(tmp_path: Path, capsys: Any) -> None:
    from fpg_gym.cli import main

    out = tmp_path / "truth_model"
    code = main(
        [
            "train-sampler", "--kind", "supervised", "--target", "truth", "--follow", "anchor",
            "--clips", "run", "--val-clips", "jump", "--scenarios", "front-many",
            "--timesteps", "12", "--epochs", "2", "--k", "8", "--latent-dim", "7",
            "--max-frames", "6", "--eval-episodes", "1", "--no-mirror", "--out", str(out),
            "--quiet",
        ]
    )  # fmt: skip
    assert code == 0
    spec = load_sampler(out).spec
    assert spec.hyperparameters["follow"] == "anchor"
    assert spec.training["target"] == "truth"
    with pytest.raises(SystemExit):
        main(["train-sampler", "--kind", "supervised", "--follow", "sideways", "--out", "x"])
