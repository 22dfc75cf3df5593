"""The Filtered Pose Graph (Plantard, Shum & Multon 2016, §4.2, Algorithms 1–4).

Nodes are normalised poses (root at the origin, facing +Z; :func:`fpg_gym.core.poses.normalise`)
filtered from mocap clips; an undirected edge joins two nodes whose FPG Eq. 1 distance
``max_j ||a(j) - b(j)||`` is below ``thres2``. The same node set is the filtered database of
Shum 2013 §V-A, so the brute-force and the graph selectors share one file.

Construction (:meth:`FilteredPoseGraph.build`):

1. **Intra-clip filter (Alg. 1)**, per clip: the first frame is kept; a later frame is kept when
   its Eq. 1 distance to the *last kept* frame exceeds ``thres1``, and that distance is recorded.
2. **thres2 (Alg. 2)** = mean + 2·std (population std) of all recorded distances, unless given.
3. **Inter-clip filter (Alg. 3)**, greedy in input order: the intra-filtered frames are visited
   clip by clip in the order the clips are given (then frame order; with ``mirror=True`` all
   original clips first, then their mirror images in the same order). A frame becomes a node
   unless its Eq. 1 distance to a node kept before it is ``<= thres1`` — to any earlier node,
   including earlier nodes of the same clip, so repeated cycles of one clip collapse too. The
   result depends on the order (a different order gives a different, equally valid
   ``thres1``-separated set); node ids follow this processing order.
4. **Edges (Alg. 4)**: an undirected edge joins nodes ``a != b`` with Eq. 1 distance ``< thres2``.

The implementation is exact (equal to the naive loops, see ``tests/test_graph.py``) and not
quadratic in practice: Alg. 1 is vectorised across clips, Alg. 3 and 4 use ``cKDTree`` with the
Chebyshev norm as a conservative prefilter followed by the exact Eq. 1 test
(:mod:`fpg_gym.graph_build`).

Files are a single ``.npz`` (``allow_pickle=False``) with a JSON ``metadata`` entry holding the
format version, the build parameters and the stats.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import json
import os
import time
import warnings
import zipfile
import zlib
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from fpg_gym import graph_build
from fpg_gym.core import skeleton
from fpg_gym.core.errors import DataFormatError
from fpg_gym.core.jsonable import jsonable
from fpg_gym.core.outputs import atomic_path
from fpg_gym.core.poses import mirror as mirror_poses
from fpg_gym.core.poses import normalise
from fpg_gym.io import DEFAULT_CLIP_NAMES, load_default_clips
from fpg_gym.io.clip import Clip
from fpg_gym.io.deepmimic import HUMANOID_TABLE
from fpg_gym.io.files import check_input_file
from fpg_gym.io.npz import check_npz
from fpg_gym.io.plausibility import check_plausible

__all__ = [
    "DEFAULT_EMBEDDED_MIRROR",
    "DEFAULT_EMBEDDED_THRES1",
    "DEFAULT_THRES1",
    "FORMAT_VERSION",
    "GRAPH_NAMES",
    "PACKAGED_GRAPHS",
    "FilteredPoseGraph",
    "cache_directory",
    "default_graph",
    "load_graph",
    "packaged_graph",
]

#: Version of the ``.npz`` layout written by :meth:`FilteredPoseGraph.save`.
FORMAT_VERSION = 1
#: FPG's thres1 in metres (paper §4.2), for adult-sized mocap such as Bandai Namco.
DEFAULT_THRES1 = 0.2
#: thres1 of :func:`default_graph`, in metres. The embedded DeepMimic database is tiny (15 clips,
#: 1,013 poses at 30 Hz) and its humanoid small (~1.34 m median pose height against ~1.75 m for
#: adult mocap). With mirroring, thres1 = 0.2 m keeps 584 nodes at a mean degree of 5.9 (sparse
#: neighbourhoods for graph selection with K = 30); 0.1 m — the paper's value scaled for the
#: smaller body and the ~500 times smaller database — keeps 1,108 nodes with a mean degree of
#: 8.0 (the paper's graph: 7.8 edges per node) and thres2 = 0.295 m.
DEFAULT_EMBEDDED_THRES1 = 0.1
#: Whether :func:`default_graph` adds left/right mirror images (doubles the tiny database).
DEFAULT_EMBEDDED_MIRROR = True

_ARRAYS = ("poses", "clip_index", "frame_index", "mirrored", "indptr", "indices", "clip_names")
#: The shapes of a graph file's arrays (``N`` nodes, ``E`` directed edges, ``C`` clips).
_SHAPES: dict[str, tuple[int | str, ...]] = {
    "poses": ("N", skeleton.NUM_JOINTS, 3),
    "clip_index": ("N",),
    "frame_index": ("N",),
    "mirrored": ("N",),
    "indices": ("E",),
    "clip_names": ("C",),
    "metadata": (),
}


def _progress_bar(enabled: bool, total: int, desc: str, unit: str) -> Any:

    return tqdm(total=total, desc=desc, unit=unit, disable=not enabled, leave=False)


def _check_build_arguments(clips: Sequence[Clip], thres1: float, thres2: float | None) -> None:
    """Refuse no clips, or a threshold that is not a positive finite distance."""
    if not clips:
        raise ValueError("clips: expected at least one clip, got none")
    for name, value in (("thres1", thres1), ("thres2", thres2)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name}: expected a positive finite distance in metres, got {value}")


def _normalised_poses(
    clips: Sequence[Clip], mirror: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every frame of the clips normalised, in clip order (with ``mirror``, the mirror images
    after all originals): the poses ``(N, 20, 3)``, each processed clip's length and the input
    clip it comes from."""
    lengths = np.array([clip.num_frames for clip in clips], dtype=np.int64)
    source_clip = np.arange(len(clips), dtype=np.int64)
    flat_poses = np.empty(
        (int(lengths.sum()) * (2 if mirror else 1), skeleton.NUM_JOINTS, 3), np.float32
    )
    position = 0
    for clip in clips:
        flat_poses[position : position + clip.num_frames] = normalise(clip.positions)[0]
        position += clip.num_frames
    if mirror:
        # Mirror images of the normalised poses still face +Z with the root at the origin.
        flat_poses[position:] = mirror_poses(flat_poses[:position])
        lengths = np.concatenate([lengths, lengths])
        source_clip = np.concatenate([source_clip, source_clip])
    return flat_poses, lengths, source_clip


class FilteredPoseGraph:
    """A Filtered Pose Graph: filtered normalised poses and their transition edges (CSR).

    Build one with :meth:`build` (or :func:`default_graph` for the embedded clips); persist it
    with :meth:`save` / :meth:`load`.

    Attributes
    ----------
    poses : ndarray, shape (N, 20, 3), float32
        Node poses, normalised (root at the origin, facing +Z).
    clip_index : ndarray, shape (N,), int32
        Source clip of each node, an index into ``clip_names``.
    frame_index : ndarray, shape (N,), int32
        Frame of each node within its source clip.
    mirrored : ndarray, shape (N,), bool
        Whether the node is the left/right mirror image of its source frame.
    clip_names : tuple of str
        Names of the input clips (mirror images share their original's name).
    indptr : ndarray, shape (N + 1,), int64
    indices : ndarray, shape (2E,), int32
        CSR adjacency: the neighbours of node ``i`` are ``indices[indptr[i]:indptr[i + 1]]``,
        sorted ascending; every edge is stored in both directions; no self loops.
    thres1, thres2 : float
        Filter and edge thresholds in metres.
    stats : dict
        Build statistics: ``poses`` (input poses, mirror images included), ``clips``,
        ``intra_nodes`` (after Alg. 1), ``nodes``, ``edges``, ``mean_degree``, ``min_degree``,
        ``max_degree``, ``isolated``, ``thres1``, ``thres2``, ``thres2_computed``, ``seconds``
        and per-stage ``seconds_*``.
    params : dict
        Build parameters: ``thres1``, ``thres2`` (as given, ``None`` when computed), ``mirror``,
        ``order``.
    """

    def __init__(
        self,
        poses: np.ndarray,
        clip_index: np.ndarray,
        frame_index: np.ndarray,
        mirrored: np.ndarray,
        indptr: np.ndarray,
        indices: np.ndarray,
        *,
        clip_names: Sequence[str],
        thres1: float,
        thres2: float,
        stats: dict[str, Any] | None = None,
        params: dict[str, Any] | None = None,
    ) -> None:
        self.poses = np.ascontiguousarray(poses, dtype=np.float32)
        n = len(self.poses)
        if self.poses.shape != (n, skeleton.NUM_JOINTS, 3):
            raise ValueError(f"poses: expected shape (N, 20, 3), got {self.poses.shape}")
        self.clip_index = np.ascontiguousarray(clip_index, dtype=np.int32)
        self.frame_index = np.ascontiguousarray(frame_index, dtype=np.int32)
        self.mirrored = np.ascontiguousarray(mirrored, dtype=bool)
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int64)
        self.indices = np.ascontiguousarray(indices, dtype=np.int32)
        self.clip_names: tuple[str, ...] = tuple(str(name) for name in clip_names)
        self.thres1 = float(thres1)
        self.thres2 = float(thres2)
        self.stats: dict[str, Any] = dict(stats or {})
        self.params: dict[str, Any] = dict(params or {})
        for name in ("clip_index", "frame_index", "mirrored"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"{name}: expected shape ({n},), got {getattr(self, name).shape}")
        if self.indptr.shape != (n + 1,) or self.indptr[0] != 0 or np.any(np.diff(self.indptr) < 0):
            raise ValueError(f"indptr: expected a non-decreasing ({n + 1},) array starting at 0")
        if self.indices.ndim != 1 or len(self.indices) != self.indptr[-1]:
            raise ValueError(
                f"indices: expected {int(self.indptr[-1])} entries, got {self.indices.shape}"
            )
        if self.indices.size and (self.indices.min() < 0 or self.indices.max() >= n):
            raise ValueError(f"indices: node ids must be in [0, {n})")
        if n and (self.clip_index.min() < 0 or self.clip_index.max() >= len(self.clip_names)):
            raise ValueError(f"clip_index: must index clip_names (0..{len(self.clip_names) - 1})")

    # ------------------------------------------------------------------ structure

    @property
    def num_nodes(self) -> int:
        """Number of nodes N."""
        return len(self.poses)

    @property
    def num_edges(self) -> int:
        """Number of undirected edges E (each stored twice in ``indices``)."""
        return int(len(self.indices) // 2)

    @property
    def degree(self) -> np.ndarray:
        """Degree of every node, ``(N,)`` int64."""
        return np.diff(self.indptr)

    def neighbors(self, i: int) -> np.ndarray:
        """Sorted neighbours of node ``i`` (a read-only view of ``indices``, int32)."""
        n = self.num_nodes
        if not -n <= i < n:
            raise IndexError(f"node {i} out of range for a graph of {n} nodes")
        i %= n
        view = self.indices[self.indptr[i] : self.indptr[i + 1]]
        view.flags.writeable = False
        return view

    def neighbors_of(
        self, nodes: np.ndarray | Sequence[int], *, include_self: bool = False
    ) -> np.ndarray:
        """Union of the neighbours of several nodes: sorted, unique node ids (intp).

        Vectorised over the CSR arrays (no Python loop over nodes, ~10 µs for 30 nodes);
        graph selection calls it every frame with the previous frame's K nodes.

        Parameters
        ----------
        nodes : array_like of int
            Node ids (duplicates allowed).
        include_self : bool
            Also include ``nodes`` themselves in the union.

        Raises
        ------
        IndexError
            If a node id is outside ``[0, num_nodes)``.
        """
        ids = np.asarray(nodes, dtype=np.intp).ravel()
        n = self.num_nodes
        if ids.size and (ids.min() < 0 or ids.max() >= n):
            raise IndexError(
                f"nodes: ids must be in [0, {n}), got min {ids.min()}, max {ids.max()}"
            )
        starts = self.indptr[ids]
        counts = self.indptr[ids + 1] - starts
        # Positions in `indices`: starts[k] + 0..counts[k]-1 for every k, without a loop.
        shift = np.repeat(starts - (np.cumsum(counts) - counts), counts)
        members = np.zeros(n, dtype=bool)
        members[self.indices[np.arange(int(counts.sum())) + shift]] = True
        if include_self:
            members[ids] = True
        return np.flatnonzero(members)

    def clip_of(self, i: int) -> str:
        """Name of the source clip of node ``i``."""
        return self.clip_names[int(self.clip_index[i])]

    def __repr__(self) -> str:
        return (
            f"FilteredPoseGraph(nodes={self.num_nodes}, edges={self.num_edges}, "
            f"thres1={self.thres1:g}, thres2={self.thres2:.4g}, clips={len(self.clip_names)})"
        )

    # ------------------------------------------------------------------ build

    @classmethod
    def build(
        cls,
        clips: Sequence[Clip],
        *,
        thres1: float = DEFAULT_THRES1,
        thres2: float | None = None,
        mirror: bool = False,
        progress: bool = True,
    ) -> FilteredPoseGraph:
        """Build the graph from mocap clips (FPG Alg. 1–4, see the module docstring).

        Parameters
        ----------
        clips : sequence of Clip
            Source clips; each frame is normalised independently. The order matters for the
            greedy inter-clip filter (earlier clips win).
        thres1 : float
            Filter threshold in metres (paper: 0.2 m).
        thres2 : float, optional
            Edge threshold in metres; by default mean + 2·std of the distances recorded by
            the intra-clip filter.
        mirror : bool
            Add the left/right mirror image of every clip (after all original clips).
        progress : bool
            Show tqdm progress bars on stderr.

        Raises
        ------
        ValueError
            If ``clips`` is empty, a threshold is not positive and finite, or thres2 cannot be
            computed (no distance recorded).
        """

        clips = list(clips)
        _check_build_arguments(clips, thres1, thres2)
        started = time.perf_counter()
        flat_poses, lengths, source_clip = _normalised_poses(clips, mirror)
        offsets = np.concatenate([[0], np.cumsum(lengths)])
        seconds_normalise = time.perf_counter() - started

        # Alg. 1: intra-clip filter, recording the distances between consecutive kept frames.
        mark = time.perf_counter()
        with _progress_bar(progress, len(flat_poses), "graph: intra-clip filter", "pose") as bar:
            kept, recorded = graph_build.intra_clip_filter(
                flat_poses, offsets, float(thres1), progress=bar.update
            )
        seconds_intra = time.perf_counter() - mark
        # Alg. 2: thres2 = mean + 2 std of the recorded distances.
        thres2_value = graph_build.compute_thres2(recorded) if thres2 is None else float(thres2)

        # Alg. 3: inter-clip filter, greedy in processing order.
        mark = time.perf_counter()
        candidates = flat_poses[kept].reshape(len(kept), -1).astype(np.float64)
        with _progress_bar(progress, len(kept), "graph: inter-clip filter", "pose") as bar:
            chosen = graph_build.inter_clip_filter(candidates, float(thres1), progress=bar.update)
        seconds_inter = time.perf_counter() - mark
        nodes = kept[chosen]

        # Alg. 4: edges under thres2.
        mark = time.perf_counter()
        indptr, indices = graph_build.build_edges(candidates[chosen], thres2_value)
        seconds_edges = time.perf_counter() - mark

        node_clip = np.searchsorted(offsets, nodes, side="right") - 1  # processed clip of node
        graph = cls(
            flat_poses[nodes],
            source_clip[node_clip],
            nodes - offsets[node_clip],
            node_clip >= len(clips),
            indptr,
            indices,
            clip_names=[clip.name for clip in clips],
            thres1=float(thres1),
            thres2=thres2_value,
            params={
                "thres1": float(thres1),
                "thres2": None if thres2 is None else float(thres2),
                "mirror": bool(mirror),
                "order": "greedy: clips in input order (mirror images after all originals), "
                "frames in order",
            },
        )
        seconds = time.perf_counter() - started
        graph.stats = {
            "poses": len(flat_poses),
            "clips": len(clips),
            "intra_nodes": len(kept),
            **graph._degree_stats(),
            "thres1": float(thres1),
            "thres2": thres2_value,
            "thres2_computed": thres2 is None,
            "mirror": bool(mirror),
            "seconds": round(seconds, 4),
            "seconds_normalise": round(seconds_normalise, 4),
            "seconds_intra": round(seconds_intra, 4),
            "seconds_inter": round(seconds_inter, 4),
            "seconds_edges": round(seconds_edges, 4),
        }
        return graph

    def _degree_stats(self) -> dict[str, Any]:
        degree = self.degree
        return {
            "nodes": self.num_nodes,
            "edges": self.num_edges,
            "mean_degree": float(degree.mean()) if degree.size else 0.0,
            "min_degree": int(degree.min()) if degree.size else 0,
            "max_degree": int(degree.max()) if degree.size else 0,
            "isolated": int(np.count_nonzero(degree == 0)),
        }

    # ------------------------------------------------------------------ persistence

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the graph to one ``.npz`` file (no pickle), atomically; returns the path.

        The archive holds the arrays ``poses``, ``clip_index``, ``frame_index``, ``mirrored``,
        ``indptr``, ``indices``, ``clip_names`` and ``metadata`` (a JSON string with
        ``format_version``, ``thres1``, ``thres2``, ``params`` and ``stats``).
        """
        target = Path(path)
        metadata = {
            "format": "fpg-gym FilteredPoseGraph",
            "format_version": FORMAT_VERSION,
            "thres1": self.thres1,
            "thres2": self.thres2,
            "params": self.params,
            "stats": self.stats,
        }
        arrays: dict[str, Any] = {
            "poses": self.poses,
            "clip_index": self.clip_index,
            "frame_index": self.frame_index,
            "mirrored": self.mirrored,
            "indptr": self.indptr,
            "indices": self.indices,
            "clip_names": np.array(self.clip_names, dtype=str).reshape(len(self.clip_names)),
            "metadata": np.array(json.dumps(jsonable(metadata))),
        }
        # Write beside the target, then rename: readers never see a half-written file.
        with atomic_path(target) as temporary, open(temporary, "xb") as stream:
            np.savez(stream, **arrays)
        return target

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> FilteredPoseGraph:
        """Read a graph written by :meth:`save`.

        Raises
        ------
        FileNotFoundError
            If the file does not exist.
        DataFormatError
            If the file is not a graph archive, is corrupt or inconsistent, or has another
            format version (the message names the file).
        """
        source = check_input_file(path)
        if not zipfile.is_zipfile(source):
            raise DataFormatError(source, "not an .npz archive (no zip directory)")
        # Forged array headers, pickled arrays, shapes that do not fit one another and archives
        # declaring more than the memory ceiling: refused before numpy inflates anything.
        check_npz(source, (*_ARRAYS, "metadata"), shapes=_SHAPES)
        try:
            loaded = np.load(source, allow_pickle=False)
            if not isinstance(loaded, np.lib.npyio.NpzFile):
                raise DataFormatError(source, "not an .npz archive (a single .npy array?)")
            with loaded as archive:
                missing = [name for name in (*_ARRAYS, "metadata") if name not in archive.files]
                if missing:
                    raise DataFormatError(
                        source, f"not an fpg-gym graph file: missing {', '.join(missing)}"
                    )
                metadata = json.loads(str(archive["metadata"][()]))
                if not isinstance(metadata, dict) or "format_version" not in metadata:
                    raise DataFormatError(
                        source, "metadata has no format_version", field="metadata"
                    )
                version = metadata["format_version"]
                if version != FORMAT_VERSION:
                    raise DataFormatError(
                        source,
                        f"graph format version {version} is not supported (this fpg-gym reads "
                        f"version {FORMAT_VERSION}); rebuild it with `fpg-gym build-graph`",
                        field="metadata",
                    )
                arrays = {name: archive[name] for name in _ARRAYS}
        except DataFormatError:
            raise
        except (
            OSError,
            ValueError,
            KeyError,
            EOFError,
            zlib.error,
            zipfile.BadZipFile,
            json.JSONDecodeError,
        ) as error:
            raise DataFormatError(source, f"corrupt or unreadable graph file ({error})") from error
        poses = arrays["poses"]
        if not np.issubdtype(poses.dtype, np.number) or not np.all(np.isfinite(poses)):
            raise DataFormatError(source, "expected finite numbers (metres)", field="poses")
        check_plausible(source, poses, field="poses")
        try:
            return cls(
                arrays["poses"],
                arrays["clip_index"],
                arrays["frame_index"],
                arrays["mirrored"],
                arrays["indptr"],
                arrays["indices"],
                clip_names=[str(name) for name in arrays["clip_names"].tolist()],
                thres1=float(metadata["thres1"]),
                thres2=float(metadata["thres2"]),
                stats=metadata.get("stats", {}),
                params=metadata.get("params", {}),
            )
        except (ValueError, KeyError, TypeError) as error:
            raise DataFormatError(source, f"inconsistent graph file: {error}") from error


# --------------------------------------------------------------------------- default graph


def cache_directory(cache_dir: str | os.PathLike[str] | None = None) -> Path:
    """The cache folder: ``cache_dir``, else ``$FPG_GYM_CACHE``, else ``~/.cache/fpg-gym``."""
    if cache_dir is not None:
        return Path(cache_dir)
    env = os.environ.get("FPG_GYM_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "fpg-gym"


#: The modules whose code decides what the default graph holds (its cache key covers them).
_DEFAULT_GRAPH_CODE = (
    "fpg_gym.graph",
    "fpg_gym.graph_build",
    "fpg_gym.io.clip",
    "fpg_gym.io.deepmimic",
    "fpg_gym.core.poses",
    "fpg_gym.core.rotations",
    "fpg_gym.core.skeleton",
)


@functools.cache
def _code_digest() -> str:
    """SHA-256 of the source of :data:`_DEFAULT_GRAPH_CODE` and of the DeepMimic reader's
    humanoid table: an edited builder never gets a graph cached by the code before it."""
    digest = hashlib.sha256()
    for name in _DEFAULT_GRAPH_CODE:
        module = importlib.import_module(name)
        digest.update(Path(str(module.__file__)).read_bytes())
    digest.update(HUMANOID_TABLE.read_bytes())
    return digest.hexdigest()


def _installed_version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:  # pragma: no cover - installed with the package
        return "unknown"


def _default_cache_key(
    exclude: Sequence[str], thres1: float, thres2: float | None, mirror: bool
) -> str:

    key = json.dumps(
        {
            "format_version": FORMAT_VERSION,
            # The distribution's version (not the root package's __version__, whose import
            # registers the env with Gymnasium: this layer imports no Gymnasium).
            "fpg_gym": _installed_version("fpg-gym"),
            "code": _code_digest(),
            "pybullet": _installed_version("pybullet"),
            "thres1": float(thres1),
            "thres2": None if thres2 is None else float(thres2),
            "mirror": bool(mirror),
            "exclude": sorted(set(exclude)),
        },
        sort_keys=True,
    )
    return hashlib.sha256(key.encode()).hexdigest()[:16]


#: Pose databases shipped with the package, by name (``--graph NAME``): ``uiprmd`` is a graph of
#: UI-PRMD's Vicon joint centres of its eight shared subjects (Vakanski et al. 2018, ODC-PDDL; see
#: ``fpg_gym/data/README.md``), in marker-based joint-centre definitions.
PACKAGED_GRAPHS: tuple[str, ...] = ("uiprmd",)
#: Names ``--graph`` accepts beside a path: the embedded DeepMimic graph and the packaged ones.
GRAPH_NAMES: tuple[str, ...] = ("default", "embedded", *PACKAGED_GRAPHS)
_DATA = Path(__file__).resolve().parent / "data"


@functools.lru_cache(maxsize=4)
def packaged_graph(name: str) -> FilteredPoseGraph:
    """A pose graph shipped with the package (:data:`PACKAGED_GRAPHS`), by name."""
    if name not in PACKAGED_GRAPHS:
        raise ValueError(
            f"graph: unknown packaged graph {name!r}; expected one of {', '.join(PACKAGED_GRAPHS)}"
        )
    return FilteredPoseGraph.load(_DATA / f"{name}-graph.npz")


def load_graph(
    graph: FilteredPoseGraph | str | os.PathLike[str] | None,
    *,
    exclude: Sequence[str] = (),
    cache_dir: str | os.PathLike[str] | None = None,
) -> FilteredPoseGraph:
    """A pose graph from what a user names: None, ``"default"`` or ``"embedded"`` is
    :func:`default_graph` without ``exclude``; a name of :data:`PACKAGED_GRAPHS` is
    :func:`packaged_graph`; a path is :meth:`FilteredPoseGraph.load`; a graph is itself.
    (Commands resolve ``"default"`` by the input's sensor first: :func:`default_graph_name`.)

    Raises
    ------
    FileNotFoundError
        If the path does not exist.
    TypeError
        If ``graph`` is none of these.
    """
    if graph is None or (isinstance(graph, str) and graph in ("default", "embedded")):
        return default_graph(exclude=exclude, cache_dir=cache_dir)
    if isinstance(graph, str) and graph in PACKAGED_GRAPHS:
        return packaged_graph(graph)
    if isinstance(graph, str | os.PathLike):
        return FilteredPoseGraph.load(graph)
    if not hasattr(graph, "poses"):
        raise TypeError(
            f"graph: expected a path, 'default', a FilteredPoseGraph or None, got "
            f"{type(graph).__name__}"
        )
    return graph


def default_graph(
    *,
    exclude: Sequence[str] = (),
    thres1: float = DEFAULT_EMBEDDED_THRES1,
    thres2: float | None = None,
    mirror: bool = DEFAULT_EMBEDDED_MIRROR,
    cache_dir: str | os.PathLike[str] | None = None,
    progress: bool = False,
) -> FilteredPoseGraph:
    """The graph of the embedded DeepMimic clips (:func:`fpg_gym.io.load_default_clips`).

    Built on first use and cached as ``default-<key>.npz`` in :func:`cache_directory`; the key
    covers the parameters, the excluded clip names, the format version, the fpg-gym and
    pybullet versions and the source of the modules that build it. An unreadable cache file is
    rebuilt; an unwritable cache folder only gives a warning.

    Parameters
    ----------
    exclude : sequence of str
        Default clip names to leave out (held-out clips, e.g. the demo's test motion).
    thres1 : float
        Filter threshold; :data:`DEFAULT_EMBEDDED_THRES1` (0.1 m) by default because the
        embedded database is tiny and its humanoid small (see the constant's comment).
    thres2 : float, optional
        Edge threshold; mean + 2·std of the intra-clip distances by default.
    mirror : bool
        Add mirror images (:data:`DEFAULT_EMBEDDED_MIRROR`).
    cache_dir : str or Path, optional
        Overrides ``$FPG_GYM_CACHE`` / ``~/.cache/fpg-gym``.
    progress : bool
        Show progress bars while building.

    Raises
    ------
    ValueError
        If ``exclude`` names an unknown clip or excludes every clip.
    """

    excluded = [str(name) for name in exclude]
    unknown = sorted(set(excluded) - set(DEFAULT_CLIP_NAMES))
    if unknown:
        raise ValueError(
            f"exclude: unknown default clip name(s) {', '.join(unknown)}; expected some of "
            + ", ".join(DEFAULT_CLIP_NAMES)
        )
    if set(DEFAULT_CLIP_NAMES) <= set(excluded):
        raise ValueError("exclude: every default clip is excluded; nothing left to build from")
    folder = cache_directory(cache_dir)
    path = folder / f"default-{_default_cache_key(excluded, thres1, thres2, mirror)}.npz"
    if path.is_file():
        try:
            return FilteredPoseGraph.load(path)
        except DataFormatError:
            pass  # stale or damaged cache entry: rebuild and overwrite it below
    clips = [clip for clip in load_default_clips() if clip.name not in set(excluded)]
    graph = FilteredPoseGraph.build(
        clips, thres1=thres1, thres2=thres2, mirror=mirror, progress=progress
    )
    graph.params["exclude"] = sorted(set(excluded))
    try:
        graph.save(path)
    except OSError as error:
        warnings.warn(f"could not cache the default graph in {folder}: {error}", stacklevel=2)
    return graph
