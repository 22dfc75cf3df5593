"""Ray beyond one process: a two-node Ray cluster on this machine, started with ``ray start``.

The head (``ray start --head`` on 127.0.0.1, no CPUs for tasks: it holds the cluster's state and
the driver) and a second node (``ray start --address``, two CPUs and a resource of its own) run
as separate raylets with their own object stores, so every task runs on the second node: the
pose graph and the recordings cross from the head's object store to the second node's, and the
tasks run in that node's worker processes. ``compare --backend ray --address`` and the
supervised sampler's training-data collection, each driven from a fresh process, give the
results of local worker processes.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from fpg_gym.experiments import run_compare
from policies.imitation import collect_imitation_data
from tests.test_compare import _config, result_rows
from tests.test_imitation import _assert_same
from tests.test_truth_target import SPEC

pytest.importorskip("ray", reason="Ray is not installed (pip install 'fpg-gym[distributed]')")

#: Ray 2.5x enables token authentication when ~/.ray/auth_token exists; a test cluster of its
#: own runs without it, and every process of the cluster and the driver must agree.
CLUSTER_ENV = {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0"}


def _free_ports(count: int) -> list[int]:
    sockets = [socket.socket() for _ in range(count)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def _node_ports(ports: list[int]) -> list[str]:
    """A node's own ports (two raylets on one machine must not share them)."""
    manager, objects, agent, agent_grpc, runtime_env, metrics = ports
    return [
        f"--node-manager-port={manager}",
        f"--object-manager-port={objects}",
        f"--dashboard-agent-listen-port={agent}",
        f"--dashboard-agent-grpc-port={agent_grpc}",
        f"--runtime-env-agent-port={runtime_env}",
        f"--metrics-export-port={metrics}",
    ]


def _stop_cluster(started: list[subprocess.Popen[bytes]], temp: Path) -> None:
    """Stop the processes of this cluster only: ``ray start`` put each node's processes in a
    session of their own (``start_new_session``), and every one of them writes into ``temp``."""
    import psutil

    sessions = {p.pid for p in started}  # a new session's id is its leader's process id
    ours = []
    for process in psutil.process_iter(["pid", "cmdline"]):
        try:
            in_session = os.getsid(process.pid) in sessions
        except (ProcessLookupError, PermissionError):
            in_session = False
        try:
            uses_temp = str(temp) in " ".join(process.info["cmdline"] or []) or any(
                str(temp) in f.path for f in process.open_files()
            )
        except (psutil.Error, OSError):
            uses_temp = False
        if process.pid != os.getpid() and (in_session or uses_temp):
            ours.append(process)
    for process in ours:
        try:
            process.send_signal(signal.SIGTERM)
        except psutil.Error:
            pass
    _, alive = psutil.wait_procs(ours, timeout=10)
    for process in alive:
        try:
            process.kill()
        except psutil.Error:
            pass


def _python(code: str, env: dict[str, str]) -> str:
    """Run ``code`` in a fresh Python process (a driver of its own: Ray keeps per-process state,
    e.g. the authentication mode of a local instance an earlier test started); its stdout."""
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-4000:]
    return done.stdout


NODES = """
import json, sys, time, ray
ray.init(address=sys.argv[1] if len(sys.argv) > 1 else "{address}", log_to_driver=False)
deadline = time.monotonic() + 60
while sum(n["Alive"] for n in ray.nodes()) < 2 and time.monotonic() < deadline:
    time.sleep(0.5)
print(json.dumps({{"alive": sum(n["Alive"] for n in ray.nodes()),
                  "resources": ray.cluster_resources()}}))
"""


@pytest.fixture(scope="module")
def two_nodes() -> Iterator[tuple[str, dict[str, str]]]:
    """The address of a running two-node cluster (a head without task CPUs and a second node
    with two) and the environment of its drivers."""
    ray_command = shutil.which("ray", path=str(Path(sys.executable).parent)) or "ray"
    temp = Path(tempfile.mkdtemp(prefix="fpgray", dir="/tmp"))  # short: Ray's socket paths
    env = dict(os.environ, **CLUSTER_ENV)
    port, *ports = _free_ports(13)
    address = f"127.0.0.1:{port}"
    common = [
        "--node-ip-address=127.0.0.1",
        "--disable-usage-stats",
        "--object-store-memory=100000000",
    ]
    head = [
        ray_command, "start", "--head", f"--port={port}", "--num-cpus=0",
        "--include-dashboard=false", f"--temp-dir={temp}", *common, *_node_ports(ports[:6]),
    ]  # fmt: skip
    second = [
        ray_command, "start", f"--address={address}", "--num-cpus=2",
        '--resources={"second_node": 2}', *common, *_node_ports(ports[6:12]),
    ]  # fmt: skip
    started: list[subprocess.Popen[bytes]] = []
    try:
        for command in (head, second):
            process = subprocess.Popen(
                command, env=env, start_new_session=True, stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
            )  # fmt: skip
            started.append(process)
            output, _ = process.communicate(timeout=120)
            if process.returncode != 0:
                pytest.fail(f"{' '.join(command[:3])} failed:\n{output.decode()[-2000:]}")
        state = json.loads(_python(NODES.format(address=address), env).splitlines()[-1])
        assert state["alive"] == 2, state
        assert state["resources"].get("second_node") == 2.0
        assert state["resources"].get("CPU") == 2.0  # all on the second node
        yield address, env
    finally:
        _stop_cluster(started, temp)
        shutil.rmtree(temp, ignore_errors=True)


def test_compare_on_two_nodes_writes_the_rows_of_local_workers(
    tmp_path: Path, two_nodes: tuple[str, dict[str, str]]
) -> None:
    address, env = two_nodes
    settings: dict[str, Any] = {"methods": ["raw", "fpg"], "seeds": [0, 1], "batch": 2}
    cluster = _config(tmp_path / "ray", backend="ray", address=address, **settings)
    # fpg-gym compare --backend ray --address ... in a process of its own (the driver).
    code = (
        "from fpg_gym.experiments import CompareConfig, run_compare; "
        f"run_compare(CompareConfig(**{vars(cluster)!r}), progress=False, plots=False)"
    )
    _python(code, env)
    local = run_compare(
        _config(tmp_path / "local", workers=2, **settings), progress=False, plots=False
    )
    assert local.tasks_run == 8
    rows = result_rows(tmp_path / "ray")
    assert len(rows) == 8 and rows == result_rows(tmp_path / "local")
    assert all(float(r["mean_error_m"]) > 0 for r in rows.values())


COLLECT = """
import sys
import numpy as np
sys.path.insert(0, {root!r})
from fpg_gym.core.defaults import DEFAULT_HOLDOUT_CLIPS
from fpg_gym.graph import default_graph
from fpg_gym.io import load_default_clips
from policies.imitation import collect_imitation_data
from policies.training import simulate_episodes
from tests.test_truth_target import SPEC
streams = simulate_episodes(load_default_clips(["walk", "punch"]), ["front-many"], [0, 1],
                            max_frames=5)
data = collect_imitation_data(default_graph(exclude=DEFAULT_HOLDOUT_CLIPS), streams, SPEC,
                              target="best", seed=3, batch=1, backend="ray", address={address!r})
np.savez({out!r}, episodes=data.episodes, actions=data.actions,
         observations=data.observations, search_energies=data.search_energies)
"""


def test_training_data_on_two_nodes_equals_local_workers(
    tmp_path: Path, graph: Any, short_streams: list[Any], two_nodes: tuple[str, dict[str, str]]
) -> None:
    address, env = two_nodes
    out = tmp_path / "pairs.npz"
    root = str(Path(__file__).resolve().parents[1])
    _python(COLLECT.format(root=root, address=address, out=str(out)), env)
    with np.load(out, allow_pickle=False) as arrays:
        on_ray = SimpleNamespace(**{name: arrays[name] for name in arrays.files})
    local = collect_imitation_data(
        graph, short_streams, SPEC, target="best", seed=3, batch=1, workers=2
    )
    assert len(on_ray.episodes) == sum(r.num_frames for r in short_streams)
    _assert_same(local, on_ray)  # type: ignore[arg-type]
