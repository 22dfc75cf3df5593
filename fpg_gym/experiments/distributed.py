"""``compare --backend ray``: a comparison's tasks on a Ray cluster (``fpg-gym[distributed]``).

Ray schedules the tasks; nothing here is a scheduler. The pose graph is put once in Ray's
object store (one copy per node, read without copying by the tasks on that node); each Ray task
is one batch of :func:`fpg_gym.experiments.run_compare` (one method on one or more episodes,
reconstructed side by side) and carries its recordings, so the workers need no shared file
system. Results come back as they finish and the caller writes them into the same resumable
``results.csv`` as the local backend (same rows, timings aside).

Pointing it at a cluster: start Ray on the machines (``ray start --head`` on one, ``ray start
--address HEAD:6379`` on the others, each with ``pip install 'fpg-gym[distributed]'``), then
``fpg-gym compare ... --backend ray --address HEAD:6379`` (or set ``RAY_ADDRESS``). Without an
address a local Ray instance is started for the run (``--workers`` CPUs) and stopped after it;
an instance the caller already started (``ray.init``) is used as it is. Two nodes on one
machine (``tests/test_ray_cluster.py``): ``ray start --head --node-ip-address 127.0.0.1 --port
P --num-cpus 0`` and ``ray start --address 127.0.0.1:P --num-cpus 2`` with ports of its own
(``--node-manager-port``, ``--object-manager-port``, the agents' and metrics ports); Ray 2.5x
turns token authentication on when ``~/.ray/auth_token`` exists, so set ``RAY_AUTH_MODE`` the
same (``disabled``, or ``token`` with the token) for the nodes and the driver.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Sequence
from typing import Any

from fpg_gym.methods import MethodRunner
from fpg_gym.runtime.ray_session import (
    RayUnavailable,
    ray_session,
    require_ray,
    restore_signals,
    signal_handlers,
    task_result,
)

__all__ = ["RayUnavailable", "require_ray", "restore_signals", "run_on_ray", "signal_handlers"]

#: Worker-process cache: one MethodRunner per run token (the graph is fetched once per process).
_RUNNERS: dict[str, Any] = {}

Work = Callable[[Any, Sequence[Any], Sequence[Any]], list[Any]]


def _ray_batch(
    token: str,
    graph: Any,
    budget: int,
    options: dict[str, Any],
    work: Work,
    tasks: Sequence[Any],
    recordings: Sequence[Any],
) -> list[Any]:
    """One Ray task: ``work(runner, tasks, recordings)`` with this process's runner for the run
    ``token`` (built on first use from the graph in the object store)."""
    runner = _RUNNERS.get(token)
    if runner is None:
        _RUNNERS.clear()  # a new run: release the previous run's runner
        runner = _RUNNERS[token] = MethodRunner(graph, budget=budget, reconstructor_options=options)
    return work(runner, tasks, recordings)


def run_on_ray(
    batches: Sequence[Sequence[Any]],
    graph: Any,
    budget: int,
    options: dict[str, Any],
    work: Work,
    load: Callable[[str], Any],
    finish: Callable[..., None],
    *,
    address: str | None = None,
    num_cpus: int | None = None,
) -> bool:
    """Run ``batches`` of compare tasks as Ray tasks; ``finish(*result)`` each result as it
    comes. True when interrupted by Ctrl-C (the queued tasks are cancelled).

    Parameters
    ----------
    batches : sequence of sequences of tasks
        Each with ``recording_path``; one Ray task per batch.
    graph : FilteredPoseGraph
        Put once in the object store.
    budget, options
        The :class:`~fpg_gym.methods.MethodRunner` settings.
    work : callable
        ``work(runner, tasks, recordings) -> list of results`` (runs in the Ray workers; a
        module-level function, so that it is sent by reference).
    load : callable
        Reads a task's recording here (the driver), to send it with the task.
    finish : callable
        Receives each result's items (the CSV row and per-frame arrays).
    address : str, optional
        Cluster address; None: ``RAY_ADDRESS`` or a local instance started here.
    num_cpus : int, optional
        CPUs of a local instance started here (None: all).
    """
    pending: dict[Any, Sequence[Any]] = {}
    with ray_session(address, num_cpus) as ray:
        try:
            token = uuid.uuid4().hex
            graph_ref = ray.put(graph)  # once: shared by every task of a node
            remote = ray.remote(num_cpus=1, max_retries=0)(_ray_batch)
            for batch in batches:
                recordings = [load(task.recording_path) for task in batch]
                ref = remote.remote(
                    token, graph_ref, budget, options, work, list(batch), recordings
                )
                pending[ref] = batch
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    pending.pop(ref)
                    for result in task_result(ray, ref):
                        finish(*result)
        except KeyboardInterrupt:
            for ref in pending:
                ray.cancel(ref, force=True)
            return True
        except BaseException:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise
    return False
