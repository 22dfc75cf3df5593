"""Filtered Pose Graph (FPG §4.2, Alg. 1–4): equality with a naive implementation, CSR
invariants, persistence, the default graph cache and the ``build-graph`` command."""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from fpg_gym import graph_build
from fpg_gym.cli import main as cli_main
from fpg_gym.core import poses
from fpg_gym.core.errors import DataFormatError
from fpg_gym.graph import FORMAT_VERSION, FilteredPoseGraph, default_graph
from fpg_gym.io import Clip, find_mocap_files, load_default_clips, read_clip

# --------------------------------------------------------------------------- naive reference


def naive_build(
    clips: list[Clip], thres1: float, thres2: float | None = None, mirror: bool = False
) -> dict[str, object]:
    """FPG Alg. 1–4 as plain loops over frames and nodes, straight from the paper's text."""
    sequences = [(c, False, poses.normalise(clip.positions)[0]) for c, clip in enumerate(clips)]
    if mirror:
        sequences += [(c, True, poses.mirror(p)) for c, _, p in list(sequences)]
    candidates: list[tuple[np.ndarray, int, int, bool]] = []
    recorded: list[float] = []
    for c, mirrored, frames in sequences:  # Alg. 1, per clip
        last = frames[0]
        candidates.append((frames[0], c, 0, mirrored))
        for f in range(1, len(frames)):
            d = float(poses.pose_distance(frames[f], last))
            if d > thres1:
                candidates.append((frames[f], c, f, mirrored))
                recorded.append(d)
                last = frames[f]
    values = np.array(recorded)
    t2 = float(np.mean(values) + 2.0 * np.std(values)) if thres2 is None else thres2  # Alg. 2
    nodes: list[tuple[np.ndarray, int, int, bool]] = []
    for candidate in candidates:  # Alg. 3, greedy in order
        if all(float(poses.pose_distance(candidate[0], node[0])) > thres1 for node in nodes):
            nodes.append(candidate)
    neighbours: list[list[int]] = [[] for _ in nodes]
    for i in range(len(nodes)):  # Alg. 4
        for j in range(i + 1, len(nodes)):
            if float(poses.pose_distance(nodes[i][0], nodes[j][0])) < t2:
                neighbours[i].append(j)
                neighbours[j].append(i)
    return {
        "poses": np.array([n[0] for n in nodes]),
        "clip_index": np.array([n[1] for n in nodes]),
        "frame_index": np.array([n[2] for n in nodes]),
        "mirrored": np.array([n[3] for n in nodes]),
        "neighbours": [sorted(row) for row in neighbours],
        "thres2": t2,
        "intra_nodes": len(candidates),
    }


def random_walk_clips(rng: np.random.Generator, count: int, frames: int) -> list[Clip]:
    """Random-walk clips around a standing pose, wandering and turning, plus a noisy repeat of
    the first clip (so that the inter-clip filter has work to do)."""
    base = poses.rest_pose()
    clips = []
    for k in range(count):
        walk = np.cumsum(rng.normal(scale=0.02, size=(frames, 20, 3)), axis=0)
        yaw = np.cumsum(rng.normal(scale=0.1, size=frames))
        local = base + walk.astype(np.float32)
        world = np.einsum("tjc,tdc->tjd", local, poses.yaw_matrix(yaw))
        world += np.cumsum(rng.normal(scale=0.05, size=(frames, 1, 3)), axis=0)
        clips.append(Clip(f"walk{k}", world.astype(np.float32), 30.0))
    repeat = clips[0].positions + rng.normal(scale=0.005, size=clips[0].positions.shape)
    clips.append(Clip("repeat", repeat.astype(np.float32), 30.0))
    return clips


def assert_matches_naive(graph: FilteredPoseGraph, naive: dict[str, object]) -> None:
    np.testing.assert_array_equal(graph.poses, naive["poses"])
    np.testing.assert_array_equal(graph.clip_index, naive["clip_index"])
    np.testing.assert_array_equal(graph.frame_index, naive["frame_index"])
    np.testing.assert_array_equal(graph.mirrored, naive["mirrored"])
    assert graph.thres2 == naive["thres2"]
    assert graph.stats["intra_nodes"] == naive["intra_nodes"]
    assert [graph.neighbors(i).tolist() for i in range(graph.num_nodes)] == naive["neighbours"]


def assert_csr_invariants(graph: FilteredPoseGraph) -> None:
    n = graph.num_nodes
    assert graph.indptr.dtype == np.int64 and graph.indices.dtype == np.int32
    assert graph.indptr.shape == (n + 1,) and graph.indptr[0] == 0
    assert graph.indptr[-1] == len(graph.indices) == 2 * graph.num_edges
    rows = np.repeat(np.arange(n), graph.degree)
    cols = graph.indices.astype(np.int64)
    assert not np.any(rows == cols), "self loop"
    forward = set(zip(rows.tolist(), cols.tolist(), strict=True))
    assert forward == {(c, r) for r, c in forward}, "adjacency is not symmetric"
    assert len(forward) == len(rows), "duplicate edge"
    for i in range(n):
        assert np.all(np.diff(graph.neighbors(i)) > 0), f"row {i} not strictly sorted"
    # Every edge is under thres2 and every node pair is thres1-separated (Alg. 3 and 4).
    if n > 1:
        d = poses.pairwise_pose_distance(graph.poses, graph.poses)
        assert np.all(d[rows, cols] < graph.thres2)
        assert np.all(d[np.triu_indices(n, 1)] > graph.thres1)


# --------------------------------------------------------------------------- equality with naive


@pytest.mark.parametrize(
    ("thres1", "thres2", "mirror"),
    [(0.2, None, False), (0.12, None, False), (0.2, 0.25, False), (0.15, None, True)],
)
def test_build_equals_naive_on_random_walks(rng, thres1, thres2, mirror):
    clips = random_walk_clips(rng, count=4, frames=60)
    graph = FilteredPoseGraph.build(
        clips, thres1=thres1, thres2=thres2, mirror=mirror, progress=False
    )
    naive = naive_build(clips, thres1, thres2, mirror)
    assert_matches_naive(graph, naive)
    assert_csr_invariants(graph)
    # The test must exercise each algorithm: some frames dropped by each filter, some edges.
    assert graph.stats["poses"] > graph.stats["intra_nodes"] > graph.num_nodes > 0
    assert graph.num_edges > 0
    assert graph.stats["thres2_computed"] == (thres2 is None)
    assert graph.params["thres2"] == thres2
    assert graph.mirrored.any() == mirror


@pytest.mark.parametrize(("thres1", "mirror"), [(0.2, False), (0.1, True)])
def test_build_equals_naive_on_default_clips(thres1, mirror):
    clips = load_default_clips()[:6]
    graph = FilteredPoseGraph.build(clips, thres1=thres1, mirror=mirror, progress=False)
    assert_matches_naive(graph, naive_build(clips, thres1, None, mirror))
    assert_csr_invariants(graph)
    assert graph.clip_names == tuple(c.name for c in clips)


def test_mirror_keeps_the_unmirrored_graph_as_prefix(rng):
    clips = random_walk_clips(rng, count=3, frames=50)
    plain = FilteredPoseGraph.build(clips, thres1=0.15, progress=False)
    mirrored = FilteredPoseGraph.build(clips, thres1=0.15, mirror=True, progress=False)
    n = plain.num_nodes
    np.testing.assert_array_equal(mirrored.poses[:n], plain.poses)
    assert not mirrored.mirrored[:n].any() and mirrored.mirrored[n:].all()
    assert mirrored.thres2 == pytest.approx(plain.thres2, rel=1e-12)
    # A mirror node is the mirror image of its source frame, normalised.
    i = n
    source = poses.normalise(clips[mirrored.clip_index[i]].positions[mirrored.frame_index[i]])[0]
    np.testing.assert_array_equal(mirrored.poses[i], poses.mirror(source))


def test_thresholds_are_strict_where_the_paper_says_so():
    base = poses.rest_pose()
    moved = base.copy()
    moved[poses.skeleton.joint_index("HandLeft"), 2] += 0.3
    d = float(poses.pose_distance(poses.normalise(base)[0], poses.normalise(moved)[0]))
    clip = Clip("tie", np.stack([base, moved, base]), 30.0)
    # Alg. 1 keeps a frame only when the distance EXCEEDS thres1: a tie is dropped.
    tie = FilteredPoseGraph.build([clip], thres1=d, thres2=1.0, progress=False)
    assert tie.stats["intra_nodes"] == 1
    # Just under the tie both frames pass Alg. 1; the third (== first) is dropped by Alg. 3
    # (distance 0 <= thres1); an edge needs dist < thres2, so thres2 == d gives none.
    below = np.nextafter(d, 0.0)
    graph = FilteredPoseGraph.build([clip], thres1=below, thres2=d, progress=False)
    assert graph.stats["intra_nodes"] == 3 and graph.num_nodes == 2 and graph.num_edges == 0
    graph = FilteredPoseGraph.build(
        [clip], thres1=below, thres2=np.nextafter(d, 1.0), progress=False
    )
    assert graph.num_edges == 1
    # Alg. 3 drops a node WITHIN thres1 (<=) of a kept one: a tie between two clips is
    # dropped, whether both are in one batch or the kept one is already in the index.
    two = [Clip("a", base[None], 30.0), Clip("b", moved[None], 30.0)]
    assert FilteredPoseGraph.build(two, thres1=d, thres2=1.0, progress=False).num_nodes == 1
    assert FilteredPoseGraph.build(two, thres1=below, thres2=1.0, progress=False).num_nodes == 2
    flat = np.stack([poses.normalise(base)[0], poses.normalise(moved)[0]]).reshape(2, 60)
    flat = flat.astype(np.float64)
    assert graph_build.inter_clip_filter(flat, d, batch=1).tolist() == [0]
    assert graph_build.inter_clip_filter(flat, below, batch=1).tolist() == [0, 1]


@pytest.mark.parametrize("block", [1, 3, 8, 64])
def test_intra_clip_filter_block_size_does_not_change_the_result(rng, block):
    clips = random_walk_clips(rng, count=3, frames=70)
    frames = np.concatenate([poses.normalise(c.positions)[0] for c in clips])
    offsets = np.concatenate([[0], np.cumsum([c.num_frames for c in clips])])
    kept, recorded = graph_build.intra_clip_filter(frames, offsets, 0.12, block=block)
    expected, expected_d = graph_build.intra_clip_filter(frames, offsets, 0.12, block=1)
    np.testing.assert_array_equal(kept, expected)
    np.testing.assert_array_equal(recorded, expected_d)
    assert np.isnan(recorded[np.isin(kept, offsets[:-1])]).all()
    assert (recorded[~np.isin(kept, offsets[:-1])] > 0.12).all()


@pytest.mark.parametrize("batch", [1, 7, 64, 4096, None])
def test_inter_clip_filter_batches_equal_the_greedy_loop(rng, batch):
    # Clustered points so that every batch has conflicts inside itself and with earlier rows.
    centres = rng.normal(scale=0.3, size=(15, 60))
    flat = centres[rng.integers(0, 15, 400)] + rng.normal(scale=0.025, size=(400, 60))
    kept = graph_build.inter_clip_filter(flat, 0.1, batch=batch)
    shaped = flat.reshape(-1, 20, 3)
    naive: list[int] = []
    for i in range(len(flat)):
        if all(float(poses.pose_distance(shaped[i], shaped[k])) > 0.1 for k in naive):
            naive.append(i)
    assert kept.tolist() == naive
    assert 30 <= len(naive) < 300  # some rows dropped, some kept beyond one per cluster


def test_build_rejects_bad_arguments(rng):
    clips = random_walk_clips(rng, count=1, frames=10)
    with pytest.raises(ValueError, match="clips"):
        FilteredPoseGraph.build([], progress=False)
    with pytest.raises(ValueError, match="thres1"):
        FilteredPoseGraph.build(clips, thres1=0.0, progress=False)
    with pytest.raises(ValueError, match="thres2"):
        FilteredPoseGraph.build(clips, thres2=float("nan"), progress=False)
    still = Clip("still", np.repeat(poses.rest_pose()[None], 5, axis=0), 30.0)
    with pytest.raises(ValueError, match=r"thres2.*cannot be computed"):
        FilteredPoseGraph.build([still], progress=False)
    single = FilteredPoseGraph.build([still], thres2=0.3, progress=False)
    assert single.num_nodes == 1 and single.num_edges == 0 and single.stats["isolated"] == 1


# --------------------------------------------------------------------------- structure


def test_neighbors_of_is_the_union_of_rows():
    graph = FilteredPoseGraph.build(load_default_clips(), thres1=0.1, progress=False)
    rng = np.random.default_rng(3)
    for size in (0, 1, 5, 30):
        nodes = rng.integers(0, graph.num_nodes, size)
        expected = sorted({int(j) for i in nodes for j in graph.neighbors(int(i))})
        got = graph.neighbors_of(nodes)
        assert got.tolist() == expected
        with_self = graph.neighbors_of(nodes, include_self=True)
        assert with_self.tolist() == sorted(set(expected) | set(nodes.tolist()))
    with pytest.raises(IndexError, match="nodes"):
        graph.neighbors_of([graph.num_nodes])
    with pytest.raises(IndexError):
        graph.neighbors(graph.num_nodes)
    assert graph.degree.sum() == 2 * graph.num_edges
    assert graph.stats["mean_degree"] == pytest.approx(graph.degree.mean())


# --------------------------------------------------------------------------- persistence


@pytest.fixture
def small_graph(rng) -> FilteredPoseGraph:
    return FilteredPoseGraph.build(
        random_walk_clips(rng, count=3, frames=40), thres1=0.12, mirror=True, progress=False
    )


def test_save_load_round_trip_is_exact(small_graph, tmp_path):
    path = small_graph.save(tmp_path / "sub" / "graph.npz")
    assert path == tmp_path / "sub" / "graph.npz" and not list(path.parent.glob("*.tmp"))
    loaded = FilteredPoseGraph.load(path)
    for name in ("poses", "clip_index", "frame_index", "mirrored", "indptr", "indices"):
        original, copy = getattr(small_graph, name), getattr(loaded, name)
        assert copy.dtype == original.dtype, name
        np.testing.assert_array_equal(copy, original, err_msg=name)
    assert loaded.clip_names == small_graph.clip_names
    assert loaded.thres1 == small_graph.thres1 and loaded.thres2 == small_graph.thres2
    assert loaded.stats == small_graph.stats and loaded.params == small_graph.params
    with np.load(path, allow_pickle=False) as archive:  # no object arrays inside
        assert json.loads(str(archive["metadata"][()]))["format_version"] == FORMAT_VERSION


def _rewrite(path: Path, target: Path, **changes: np.ndarray) -> None:
    with np.load(path, allow_pickle=False) as archive:
        arrays = {name: archive[name] for name in archive.files}
    arrays.update(changes)
    np.savez(target, **arrays)


def test_load_rejects_other_versions_and_corrupt_files(small_graph, tmp_path):
    path = small_graph.save(tmp_path / "graph.npz")
    with np.load(path, allow_pickle=False) as archive:
        metadata = json.loads(str(archive["metadata"][()]))
    metadata["format_version"] = FORMAT_VERSION + 1
    _rewrite(path, tmp_path / "v2.npz", metadata=np.array(json.dumps(metadata)))
    with pytest.raises(DataFormatError, match=r"v2\.npz.*version 2 is not supported"):
        FilteredPoseGraph.load(tmp_path / "v2.npz")

    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(DataFormatError, match=r"truncated\.npz"):
        FilteredPoseGraph.load(truncated)

    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file at all")
    with pytest.raises(DataFormatError, match=r"garbage\.npz"):
        FilteredPoseGraph.load(garbage)

    _rewrite(path, tmp_path / "badcsr.npz", indices=small_graph.indices[:-1])
    with pytest.raises(DataFormatError, match=r"badcsr\.npz.*indices"):
        FilteredPoseGraph.load(tmp_path / "badcsr.npz")

    with zipfile.ZipFile(tmp_path / "other.npz", "w") as archive:
        archive.writestr("x.npy", b"")
    with pytest.raises(DataFormatError, match=r"other\.npz.*missing"):
        FilteredPoseGraph.load(tmp_path / "other.npz")

    np.save(tmp_path / "array.npy", small_graph.poses)
    with pytest.raises(DataFormatError, match=r"array\.npy.*not an \.npz"):
        FilteredPoseGraph.load(tmp_path / "array.npy")

    with pytest.raises(FileNotFoundError):
        FilteredPoseGraph.load(tmp_path / "absent.npz")


def test_default_graph_is_cached_and_honours_exclude(tmp_path, monkeypatch):
    monkeypatch.setenv("FPG_GYM_CACHE", str(tmp_path / "env-cache"))
    first = default_graph(exclude=["walk"])
    files = list((tmp_path / "env-cache").glob("default-*.npz"))
    assert len(files) == 1
    assert "walk" not in first.clip_names and len(first.clip_names) == 14
    assert first.num_nodes >= 300, "too few candidates for K = 30 selection"
    again = default_graph(exclude=["walk"])
    np.testing.assert_array_equal(again.poses, first.poses)
    assert again.stats == first.stats  # read back from the cache (stats hold build seconds)
    other = default_graph(exclude=["walk", "run"], cache_dir=tmp_path / "explicit")
    assert len(list((tmp_path / "explicit").glob("default-*.npz"))) == 1
    assert other.num_nodes < first.num_nodes
    files[0].write_bytes(b"damaged")  # a damaged cache entry is rebuilt, not fatal
    rebuilt = default_graph(exclude=["walk"])
    np.testing.assert_array_equal(rebuilt.poses, first.poses)
    with pytest.raises(ValueError, match="unknown default clip"):
        default_graph(exclude=["moonwalk"])


def test_default_graph_cache_key_covers_the_code_that_builds_it(monkeypatch):
    from fpg_gym import graph as graph_module

    key = graph_module._default_cache_key(["walk"], 0.2, None, True)
    assert key == graph_module._default_cache_key(["walk"], 0.2, None, True)
    assert key != graph_module._default_cache_key(["run"], 0.2, None, True)
    monkeypatch.setattr(graph_module, "_code_digest", lambda: "edited builder")
    assert key != graph_module._default_cache_key(["walk"], 0.2, None, True)


def test_tests_never_use_the_users_cache():
    cache = Path(os.environ["FPG_GYM_CACHE"]).resolve()
    assert Path.home().resolve() / ".cache" not in cache.parents


# --------------------------------------------------------------------------- CLI and real data


def test_build_graph_cli_json(tmp_path, capsys):
    out = tmp_path / "default.npz"
    status = cli_main(
        ["build-graph", "default", "--out", str(out), "--thres1", "0.15", "--mirror", "--json"]
    )
    assert status == 0
    lines = capsys.readouterr().out.strip().splitlines()
    summary = json.loads(lines[-1])
    for key in ("poses", "nodes", "edges", "mean_degree", "thres1", "thres2", "seconds"):
        assert key in summary, key
    graph = FilteredPoseGraph.load(out)
    assert summary["nodes"] == graph.num_nodes and summary["edges"] == graph.num_edges
    assert summary["poses"] == 2 * sum(c.num_frames for c in load_default_clips())
    assert summary["thres1"] == 0.15 and summary["thres2"] == graph.thres2
    assert any(line.startswith("isolated nodes") for line in lines)


def test_build_graph_cli_reports_bad_input(tmp_path, capsys):
    status = cli_main(["build-graph", str(tmp_path / "nothing"), "--out", str(tmp_path / "g.npz")])
    assert status == 2
    assert "nothing" in capsys.readouterr().err


def test_real_bandai_files_build_like_naive():
    folder = shared_path("bandai_namco", "dataset-1")
    files = find_mocap_files([folder])[:3]
    clips = [read_clip(f) for f in files]
    # Keep the naive reference cheap: the first 150 frames of each take.
    clips = [Clip(c.name, c.positions[:150], c.fps) for c in clips]
    graph = FilteredPoseGraph.build(clips, thres1=0.2, progress=False)
    assert_matches_naive(graph, naive_build(clips, 0.2))
    assert_csr_invariants(graph)
    assert 0.2 < graph.thres2 < 0.6


def test_load_graph_resolves_names_paths_and_objects(tmp_path: Path) -> None:
    from fpg_gym.graph import load_graph

    embedded = load_graph("default", exclude=["walk"], cache_dir=tmp_path)
    assert "walk" not in embedded.clip_names
    path = tmp_path / "g.npz"
    embedded.save(path)
    assert load_graph(path).num_nodes == embedded.num_nodes
    assert load_graph(embedded) is embedded
    with pytest.raises(FileNotFoundError):
        load_graph(tmp_path / "missing.npz")
    with pytest.raises(TypeError, match="expected a path"):
        load_graph(3)  # type: ignore[arg-type]
