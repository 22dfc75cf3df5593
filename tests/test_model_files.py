"""Learned-sampler model files are data: loading one never runs code from it (issue 16, item 1).

A crafted stable-baselines3 ``.zip`` and a crafted pickle named ``.pt`` each carry a payload that
would create a file when unpickled; loading must refuse them with the project's error, and the
file must not appear. The RL sampler round-trips through the tensor format.
"""

from __future__ import annotations

import base64
import json
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import optimizers
from fpg_gym.core.errors import DataFormatError, FpgGymError
from policies.loading import load_sampler
from policies.sampler import FORMAT, SamplerSpec

torch = pytest.importorskip("torch")
pytest.importorskip("stable_baselines3")

LATENT, CANDIDATES = 4, 5


class _Payload:
    """Unpickling this creates ``marker`` (stands in for any code an attacker would run)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (exec, (f"open({str(self.marker)!r}, 'w').close()",))


def _spec(kind: str = "rl", algo: str = "ppo", **kwargs: Any) -> SamplerSpec:
    return SamplerSpec.for_layout(kind, algo, LATENT, CANDIDATES, action_mode="absolute", **kwargs)


def _write_json(path: Path, spec: SamplerSpec, weights: str, version: int = 1) -> Path:
    data = {**spec.to_json(), "weights": weights, "version": version}
    path.write_text(json.dumps(data))
    return path


def _crafted_sb3_zip(path: Path, marker: Path) -> None:
    """An SB3-style model zip whose ``data`` entry holds a serialized (pickled) object."""
    serialized = base64.b64encode(pickle.dumps(_Payload(marker))).decode()
    data = {
        "policy_class": {":type:": "<class 'type'>", ":serialized:": serialized},
        "n_envs": 1,
    }
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("data", json.dumps(data))
        archive.writestr("_stable_baselines3_version", "2.3.0")


def test_a_crafted_sb3_zip_is_refused_and_its_payload_never_runs(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    _crafted_sb3_zip(tmp_path / "model.zip", marker)
    _write_json(tmp_path / "model.json", _spec(), "model.zip")
    for name in ("model", "model.json", "model.zip"):
        with pytest.raises(DataFormatError, match=r"model\.zip.*refused.*pickled") as info:
            load_sampler(tmp_path / name)
        assert isinstance(info.value, FpgGymError)
    with pytest.raises(DataFormatError, match="refused"):
        optimizers.make(f"learned:{tmp_path / 'model'}")
    assert not marker.exists(), "loading the model ran code from it"


def test_a_pickle_named_pt_is_refused_and_its_payload_never_runs(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    (tmp_path / "model.pt").write_bytes(pickle.dumps({"w": _Payload(marker)}, protocol=2))
    for kind, algo in (("rl", "ppo"), ("supervised", "mlp")):
        _write_json(tmp_path / "model.json", _spec(kind, algo), "model.pt", version=2)
        with pytest.raises(DataFormatError, match=r"model\.pt.*only tensor files"):
            load_sampler(tmp_path / "model")
    assert not marker.exists(), "loading the model ran code from it"


def test_a_torch_archive_with_a_payload_is_refused(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    torch.save({"weight": torch.zeros(2), "evil": _Payload(marker)}, tmp_path / "model.pt")
    assert not marker.exists()
    _write_json(tmp_path / "model.json", _spec(), "model.pt", version=2)
    with pytest.raises(DataFormatError, match=r"model\.pt.*only tensor files"):
        load_sampler(tmp_path / "model")
    assert not marker.exists(), "loading the model ran code from it"


@pytest.mark.parametrize(
    ("weights", "message"),
    [("../elsewhere.pt", "expected a file name beside the JSON"), ("model.pkl", "refused")],
)
def test_weights_must_be_a_tensor_file_beside_the_json(
    tmp_path: Path, weights: str, message: str
) -> None:
    _write_json(tmp_path / "model.json", _spec(), weights, version=2)
    with pytest.raises(DataFormatError, match=message):
        load_sampler(tmp_path / "model")


@pytest.mark.parametrize(
    ("hyper", "field"),
    [
        ({"net_arch": [10**9]}, "net_arch"),
        ({"net_arch": "big"}, "net_arch"),
        ({"log_std_init": "x"}, "log_std_init"),
    ],
)
def test_a_hostile_architecture_is_refused_before_building(
    tmp_path: Path, hyper: dict[str, Any], field: str
) -> None:
    torch.save({"w": torch.zeros(1)}, tmp_path / "model.pt")
    _write_json(tmp_path / "model.json", _spec(hyperparameters=hyper), "model.pt", version=2)
    with pytest.raises(DataFormatError, match=field):
        load_sampler(tmp_path / "model")


def test_a_bad_json_is_a_project_error(tmp_path: Path) -> None:
    (tmp_path / "a.json").write_text("{not json")
    (tmp_path / "b.json").write_text(json.dumps({"format": FORMAT, "version": "x"}))
    (tmp_path / "c.json").write_text(json.dumps({"format": FORMAT, "kind": "rl"}))
    for name in ("a", "b", "c"):
        with pytest.raises(DataFormatError, match=rf"{name}\.json"):
            load_sampler(tmp_path / name)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_the_rl_sampler_round_trips_through_tensors_and_json(tmp_path: Path, algo: str) -> None:
    from policies.rl import RLSampler

    spec = _spec(algo=algo, hyperparameters={"net_arch": [16, 16], "log_std_init": -0.5})
    policy = RLSampler.build_policy(spec)
    with torch.no_grad():
        for parameter in policy.parameters():  # not the initial weights: a real round trip
            parameter.add_(0.05 * torch.randn_like(parameter))
    sampler = RLSampler(spec, policy, seed=0)
    path = sampler.save(tmp_path / "rl")
    assert path.name == "rl.json" and (tmp_path / "rl.pt").is_file()
    assert not (tmp_path / "rl.zip").exists()
    saved = json.loads(path.read_text())
    assert saved["weights"] == "rl.pt" and saved["hyperparameters"]["net_arch"] == [16, 16]
    state = torch.load(tmp_path / "rl.pt", weights_only=True)
    assert all(isinstance(v, torch.Tensor) for v in state.values())
    loaded = load_sampler(tmp_path / "rl")
    assert isinstance(loaded, RLSampler)
    observation = np.random.default_rng(0).normal(size=(3, spec.observation_size))
    mean, std = sampler.gaussian(observation.astype(np.float32))
    loaded_mean, loaded_std = loaded.gaussian(observation.astype(np.float32))
    np.testing.assert_allclose(loaded_mean, mean, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(loaded_std, std, rtol=1e-6, atol=1e-7)


def test_tensors_of_another_network_are_refused(tmp_path: Path) -> None:
    from policies.rl import RLSampler

    spec = _spec(hyperparameters={"net_arch": [16]})
    RLSampler(spec, RLSampler.build_policy(spec)).save(tmp_path / "rl")
    data = json.loads((tmp_path / "rl.json").read_text())
    data["hyperparameters"]["net_arch"] = [8]
    (tmp_path / "rl.json").write_text(json.dumps(data))
    with pytest.raises(DataFormatError, match=r"rl\.pt.*do not fit the network"):
        load_sampler(tmp_path / "rl")


def test_the_cli_refuses_a_crafted_model_on_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from fpg_gym.cli import main

    marker = tmp_path / "pwned"
    _crafted_sb3_zip(tmp_path / "model.zip", marker)
    _write_json(tmp_path / "model.json", _spec(), "model.zip")
    argv = ["reconstruct", "--input", str(tmp_path / "missing.npz"), "--graph", "default"]
    argv += ["--optimizer", f"learned:{tmp_path / 'model'}", "--out", str(tmp_path / "o.npz")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("fpg-gym reconstruct: error: ")
    assert "refused" in err[0] and "model.zip" in err[0]
    assert not marker.exists(), "loading the model ran code from it"
