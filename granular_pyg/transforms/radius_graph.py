"""Radius graph between particles: every pair closer than the cut-off, never truncated.

Two backends give identical edge sets: ``scipy`` (``cKDTree.query_pairs``) and ``torch_cluster``
(``torch_cluster.radius``). Each only proposes candidate pairs, searched with a radius inflated
by a few ulps; the final, shared test is

.. math::

    (x_i - x_j)^2 + (y_i - y_j)^2 + (z_i - z_j)^2 < r^2

evaluated in the input dtype in that fixed order (with :math:`r^2` rounded to the input
dtype), so the backends' own round-off can neither add nor drop an edge.

Unlike PyG's ``radius_graph`` (32 neighbours by default, extra ones dropped silently), a node
never loses a neighbour here: without ``max_num_neighbors`` the cap is sized to fit, and with
one, a node that has more neighbours raises :class:`~granular_pyg.errors.InputError`.
"""

from __future__ import annotations

import math
import numbers
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import torch
from torch_geometric.data import Data
from torch_geometric.transforms import BaseTransform

from granular_pyg.errors import InputError, check_tensor

__all__ = ["BACKENDS", "RadiusGraph", "radius_graph"]

BACKENDS = ("auto", "scipy", "torch_cluster")

# First neighbour cap (self excluded) of the doubling search on CUDA, where torch_cluster
# allocates [num_nodes, cap] results. About the neighbour count of packed spheres at a cut-off of
# 2.5 spacings (4/3 pi 2.5^3 = 65 lattice sites), so a packed bed needs at most one redo.
FIRST_CAP_CUDA = 64

# Points per torch thread above which the scipy search is split into slabs, one per thread.
SLAB_POINTS = 1000

# Candidate searches use radius * (1 + _SLACK_ULPS * eps(dtype)): a superset of the exact test.
_SLACK_ULPS = 64


def _has_torch_cluster() -> bool:
    try:
        import torch_cluster  # noqa: F401
    except ImportError:
        return False
    return True


def _checked_radius(radius: float) -> float:
    if (
        isinstance(radius, bool)
        or not isinstance(radius, numbers.Real)
        or not (radius > 0 and math.isfinite(radius))
    ):
        raise InputError(f"radius: expected a positive finite distance (m), got {radius!r}")
    return float(radius)


def _checked_backend(backend: str) -> str:
    if not isinstance(backend, str) or backend not in BACKENDS:
        choices = ", ".join(map(repr, BACKENDS))
        raise InputError(f"backend: expected one of {choices}, got {backend!r}")
    return backend


def _checked_max_num_neighbors(max_num_neighbors: int | None) -> int | None:
    if max_num_neighbors is None:
        return None
    if isinstance(max_num_neighbors, bool) or not isinstance(max_num_neighbors, (int, np.integer)):
        raise InputError(
            "max_num_neighbors: expected a positive int or None (sized automatically), "
            f"got {max_num_neighbors!r}"
        )
    if max_num_neighbors < 1:
        raise InputError(
            "max_num_neighbors: expected a positive int or None (sized automatically), "
            f"got {max_num_neighbors}"
        )
    return int(max_num_neighbors)


def _sq_dist(pos: torch.Tensor, target: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
    """``[E]`` squared distances (m^2) in ``pos.dtype``, always in the same operation order."""
    d = pos.index_select(0, target) - pos.index_select(0, source)
    d = d * d
    return (d[:, 0] + d[:, 1]) + d[:, 2]


def _columns(coords: np.ndarray) -> np.ndarray:
    """``[3, N]`` C-contiguous coordinate columns of ``[N, 3]`` ``coords``: gathers from a
    column are 4-5x faster than from rows, and min/max over the columns, copy included, 16x
    faster than over axis 0 of the rows (2k points)."""
    return np.ascontiguousarray(coords.T)


def _within(columns: np.ndarray, i: np.ndarray, j: np.ndarray, r2: np.floating) -> np.ndarray:
    """``[P]`` bool: the exact test on the CPU from ``[3, N]`` coordinate columns
    (:func:`_columns`); the same operations in the same order as :func:`_sq_dist`."""
    total = None
    for col in columns:
        d = col[i] - col[j]
        d *= d
        total = d if total is None else total + d
    return total < r2


def _split_keys(keys: np.ndarray) -> torch.Tensor:
    """``[2, E]`` (source, target) of sorted 64-bit keys ``target << 32 | source``."""
    out = np.empty((2, keys.shape[0]), dtype=np.int64)
    np.bitwise_and(keys, 0xFFFFFFFF, out=out[0])
    np.right_shift(keys, 32, out=out[1])
    return torch.from_numpy(out)


def _sorted_by_target(target: torch.Tensor, source: torch.Tensor) -> torch.Tensor:
    """``[2, E]`` edge index sorted by ``(target, source)``: one sort of 64-bit keys
    ``target << 32 | source`` (a value sort is ~3x faster than an argsort) and bit operations
    to split them."""
    keys = (target << 32) | source
    if keys.device.type != "cpu":
        keys = torch.sort(keys).values
        return torch.stack([keys & 0xFFFFFFFF, keys >> 32])
    flat = keys.numpy()
    flat.sort()
    return _split_keys(flat)


def _sorted_pair_keys(i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Sorted keys ``target << 32 | source`` of both directions of the pairs ``(i, j)``."""
    m = i.shape[0]
    keys = np.empty(2 * m, dtype=np.int64)
    np.left_shift(i, 32, out=keys[:m])
    keys[:m] |= j
    np.left_shift(j, 32, out=keys[m:])
    keys[m:] |= i
    keys.sort()  # numpy's sort releases the GIL: slabs sort in parallel
    return keys


_POOL: ThreadPoolExecutor | None = None


def _thread_pool(workers: int) -> ThreadPoolExecutor:
    """A shared pool of at least ``workers`` threads."""
    global _POOL
    if _POOL is None or _POOL._max_workers < workers:
        _POOL = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="radius_graph")
    return _POOL


def _search_radius(radius: float, dtype: torch.dtype) -> float:
    """Candidate-search radius (m): ``radius`` inflated a few ulps of ``dtype``."""
    return radius * (1.0 + _SLACK_ULPS * torch.finfo(dtype).eps)


def _slab_pairs(
    coords64: np.ndarray,
    columns: np.ndarray,
    radius: float,
    search: float,
    members: np.ndarray | None,
    crosses: list[tuple[np.ndarray, np.ndarray]],
    sort: bool,
) -> tuple[np.ndarray, np.ndarray] | np.ndarray:
    """``(i, j)`` exact pairs within one slab (``members``; None: every point), plus, for each
    ``(near_below, near_above)`` of ``crosses``, those between points just below a face and
    points just above it (indices into ``coords64``, ``[N, 3]``; ``columns``: the ``[3, N]``
    columns of the input dtype for the exact test); with ``sort``, the sorted keys of both
    directions instead (:func:`_sorted_pair_keys`)."""
    from scipy.spatial import cKDTree

    if members is None:
        inner = cKDTree(coords64).query_pairs(search, output_type="ndarray")
        i, j = inner.T.copy()  # contiguous columns: the gathers below are 2x faster
    elif members.size > 1:
        inner = cKDTree(coords64[members]).query_pairs(search, output_type="ndarray")
        i, j = members[inner.T.copy()]
    else:
        i = j = np.empty(0, dtype=np.int64)
    for near_below, near_above in crosses:
        if near_below.size and near_above.size:
            cross = cKDTree(coords64[near_below]).sparse_distance_matrix(
                cKDTree(coords64[near_above]), search, output_type="ndarray"
            )
            i = np.concatenate([i, near_below[cross["i"]]])
            j = np.concatenate([j, near_above[cross["j"]]])
    keep = _within(columns, i, j, columns.dtype.type(radius * radius))
    if not keep.all():
        i, j = i[keep], j[keep]
    return _sorted_pair_keys(i, j) if sort else (i, j)


def _slabs(x: np.ndarray, parts: int, search: float) -> np.ndarray | None:
    """Inner faces ``[parts - 1]`` (m) cutting ``x`` into ``parts`` slabs of about equal counts,
    each thicker than ``search`` (so only neighbouring slabs share pairs); None if impossible."""
    ranks = (np.arange(1, parts) * x.shape[0]) // parts
    faces = np.partition(x, ranks)[ranks]  # a partial sort: 5x faster than np.quantile
    return None if np.any(np.diff(faces) <= search) else faces


def _scipy_edges(pos: torch.Tensor, radius: float, sort: bool) -> torch.Tensor:
    """``[2, E]`` (source, target) of both directions of every exact pair, via
    ``cKDTree.query_pairs`` (CPU): sorted by ``(target, source)`` with ``sort``, otherwise in a
    deterministic order of the search.

    Above ``SLAB_POINTS`` points per torch thread, the points are cut across their longest
    axis into one slab per thread, each searched (and, with ``sort``, its keys sorted) in its
    own thread (scipy's searches and numpy's sorts release the GIL; the calling thread takes the
    first slab) together with half the pairs across each of its faces (the points below a face
    split between the slabs on either side, so that every thread has about the same work); the
    sorted runs of the slabs are then merged by one stable sort, which numpy's timsort does in
    linear time."""
    pos = pos.cpu()
    coords64 = pos.double().numpy()
    columns = _columns(pos.numpy())
    n = coords64.shape[0]
    parts = max(1, min(torch.get_num_threads(), n // SLAB_POINTS))
    search = _search_radius(radius, pos.dtype)
    faces = None
    if parts > 1:
        # numpy, not torch: a torch reduction here wakes torch's thread pool, which then
        # competes with the slab threads (measured: 2k points 1.5x slower)
        columns64 = _columns(coords64)
        x = columns64[int(np.argmax(columns64.max(axis=1) - columns64.min(axis=1)))]
        faces = _slabs(x, parts, search)
    if faces is None:
        found = [_slab_pairs(coords64, columns, radius, search, None, [], sort)]
    else:
        slab = np.searchsorted(faces, x, side="right")  # slab s holds faces[s-1] <= x < faces[s]
        order = np.argsort(slab, kind="stable")
        starts = np.concatenate([[0], np.cumsum(np.bincount(slab, minlength=parts))])
        members = [order[starts[s] : starts[s + 1]] for s in range(parts)]
        crosses = [[] for _ in range(parts)]
        for s in range(parts - 1):  # face s: slab s gets half its points below, s + 1 the rest
            below = members[s][x[members[s]] >= faces[s] - search]
            above = members[s + 1][x[members[s + 1]] < faces[s] + search]
            crosses[s].append((below[0::2], above))
            crosses[s + 1].append((below[1::2], above))
        jobs = [
            (coords64, columns, radius, search, members[s], crosses[s], sort) for s in range(parts)
        ]
        pool = _thread_pool(parts - 1)
        pending = [pool.submit(_slab_pairs, *job) for job in jobs[1:]]
        found = [_slab_pairs(*jobs[0])] + [job.result() for job in pending]
    if sort:
        keys = found[0] if len(found) == 1 else np.sort(np.concatenate(found), kind="stable")
        return _split_keys(keys)
    k = sum(i.shape[0] for i, _ in found)
    out = np.empty((2, 2 * k), dtype=np.int64)
    at = 0
    for i, j in found:
        m = i.shape[0]
        out[0, at : at + m], out[1, at : at + m] = j, i
        out[0, k + at : k + at + m], out[1, k + at : k + at + m] = i, j
        at += m
    return torch.from_numpy(out)


def _torch_cluster_candidates(
    pos: torch.Tensor, radius: float, first_cap: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(target, source)`` of every pair within ``radius`` (self pairs included), never truncated.

    ``torch_cluster.radius`` keeps at most ``cap`` neighbours (the node itself included) per
    node. Whenever a node reaches the cap, some may have been dropped: double it and search
    again, up to ``num_nodes`` (then nothing can be dropped).

    Args:
        pos: ``[N, 3]`` positions (m), any device.
        radius: search radius (m).
        first_cap: first neighbour cap, the node itself excluded.
    """
    import torch_cluster

    n = pos.shape[0]
    cap = min(first_cap + 1, n)
    while True:
        raw = torch_cluster.radius(pos, pos, radius, max_num_neighbors=cap)  # [0]: query
        if cap >= n or int(torch.bincount(raw[0], minlength=n).max()) < cap:
            break
        cap = min(2 * cap, n)
    return raw[0], raw[1]


def _torch_cluster_pairs(
    pos: torch.Tensor, radius: float, first_cap: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(target, source)`` of every exact pair (both directions come out of the search)."""
    search = _search_radius(radius, pos.dtype)
    target, source = _torch_cluster_candidates(pos, search, first_cap)
    r2 = torch.tensor(radius * radius, dtype=pos.dtype, device=pos.device)
    keep = (_sq_dist(pos, target, source) < r2) & (target != source)
    return target[keep], source[keep]


def _radius_graph(
    pos: torch.Tensor,
    radius: float,
    backend: str,
    max_num_neighbors: int | None,
    pos_name: str,
    sort: bool = True,
) -> torch.Tensor:
    check_tensor(pos_name, pos, (None, 3))
    n = pos.shape[0]
    if n >= 2**31:
        raise InputError(f"{pos_name}: at most 2^31 - 1 points, got {n}; split the scene")
    if n < 2:
        return torch.empty(2, 0, dtype=torch.long, device=pos.device)
    pos = pos.detach()
    if backend == "auto":
        backend = (
            "scipy" if pos.device.type == "cpu" or not _has_torch_cluster() else "torch_cluster"
        )
    if backend == "scipy":
        edge_index = _scipy_edges(pos, radius, sort)
    else:
        # On the CPU torch_cluster finds every neighbour anyway and the cap only trims the output,
        # so one uncapped search is cheapest; on CUDA the cap sizes the result buffer.
        if pos.device.type == "cpu":
            first_cap = n
        else:
            first_cap = FIRST_CAP_CUDA if max_num_neighbors is None else max_num_neighbors
        target, source = _torch_cluster_pairs(pos, radius, first_cap)
        edge_index = _sorted_by_target(target, source) if sort else torch.stack([source, target])
    edge_index = edge_index.to(pos.device)
    if max_num_neighbors is not None and edge_index.shape[1] > 0:
        degree = torch.bincount(edge_index[1], minlength=n)
        over = int((degree > max_num_neighbors).sum())
        if over:
            raise InputError(
                f"max_num_neighbors: {over} of {n} nodes have more than {max_num_neighbors} "
                f"neighbours within radius {radius:g} m (max degree {int(degree.max())}); "
                "raise max_num_neighbors or pass None to size it automatically"
            )
    return edge_index


def radius_graph(
    pos: torch.Tensor,
    radius: float,
    backend: str = "auto",
    max_num_neighbors: int | None = None,
    sort: bool = True,
) -> torch.Tensor:
    """Edges between every pair of points closer than ``radius``, both directions, no loops.

    An edge ``(j, i)`` exists iff ``i != j`` and ``(pos[i] - pos[j])**2`` summed over x, y, z
    (in that order, in ``pos.dtype``) is strictly below ``radius**2`` (rounded to
    ``pos.dtype``): a pair exactly ``radius`` apart is not connected, coincident points are.
    Both backends give the same edge set, and with ``sort=True`` the identical, identically
    ordered ``edge_index``.

    Backends (candidate search only; the exact test above is shared):

    - ``"scipy"``: ``scipy.spatial.cKDTree.query_pairs`` on the CPU in float64 (``pos`` on
      another device is copied to the CPU and the result copied back). From
      ``SLAB_POINTS`` (1,000) points per torch thread on, the points are cut into one slab per
      thread across their longest axis and the slabs are searched in parallel.
    - ``"torch_cluster"``: ``torch_cluster.radius`` on ``pos``'s device. On CUDA its neighbour
      cap starts at ``max_num_neighbors`` (or 64 when None) and doubles while some node reaches
      it; on the CPU the search is uncapped (it costs the same).
    - ``"auto"``: ``"scipy"`` on the CPU, ``"torch_cluster"`` on CUDA (``"scipy"`` where
      torch_cluster is not installed). On the CPU scipy is
      faster: ``python -m granular_pyg.bench suite=radius_graph`` (2 cores, 2 torch threads,
      float32 points on a jittered 3 mm lattice, radius 7.5 mm, 58-68 neighbours per point;
      whole function, median of 5 after a warm-up) took 7.4 / 45 / 221 ms with scipy against
      14.5 / 82 / 439 ms with torch_cluster at 2,000 / 10,000 / 50,000 points (1.8-2.0x).
      Against bare (single-threaded) ``cKDTree(pos).query_pairs(r)`` see ``python -m
      granular_pyg.bench suite=neighbours``.

    Args:
        pos: ``[num_nodes, 3]`` positions (m), float32 or float64, finite, any device.
        radius: cut-off distance (m), positive and finite.
        backend: ``"auto"``, ``"scipy"`` or ``"torch_cluster"``.
        max_num_neighbors: most neighbours a node may have; None (default) allows any number.
            Both backends raise rather than drop an edge when a node has more.
        sort: order the edges by ``(target, source)`` (the same order for every backend and
            run); False: the backend's own (deterministic) order, one sort cheaper.

    Returns:
        ``edge_index: [2, num_edges]`` int64 on ``pos.device``; ``edge_index[0]`` is the source
        ``j``, ``edge_index[1]`` the target ``i`` (PyG ``source_to_target``), sorted by
        ``(target, source)`` when ``sort``. Every pair appears in both directions. Empty
        ``[2, 0]`` when ``num_nodes < 2``.

    Raises:
        InputError: ``pos`` of the wrong shape or dtype or with NaN/Inf; ``radius`` not positive
            and finite; an unknown ``backend``; a node with more than ``max_num_neighbors``
            neighbours (naming the count of such nodes and the largest degree).
    """
    return _radius_graph(
        pos,
        _checked_radius(radius),
        _checked_backend(backend),
        _checked_max_num_neighbors(max_num_neighbors),
        "pos",
        bool(sort),
    )


class RadiusGraph(BaseTransform):
    """Set ``data.edge_index`` to the radius graph of ``data.pos`` (see :func:`radius_graph`).

    Args:
        radius: cut-off distance (m), positive and finite.
        backend: ``"auto"``, ``"scipy"`` or ``"torch_cluster"``.
        max_num_neighbors: most neighbours a node may have (InputError beyond); None: any.

    Example:
        >>> data = RadiusGraph(0.0075)(Data(pos=torch.rand(100, 3) * 0.05))
        >>> data.edge_index.shape[0]
        2
    """

    def __init__(
        self, radius: float, backend: str = "auto", max_num_neighbors: int | None = None
    ) -> None:
        self.radius = _checked_radius(radius)
        self.backend = _checked_backend(backend)
        self.max_num_neighbors = _checked_max_num_neighbors(max_num_neighbors)

    def forward(self, data: Data) -> Data:
        """Read ``data.pos: [num_nodes, 3]`` (m); set ``data.edge_index: [2, num_edges]``."""
        pos = getattr(data, "pos", None)
        if pos is None:
            raise InputError("data.pos: missing; set the [num_nodes, 3] positions (m) first")
        data.edge_index = _radius_graph(
            pos, self.radius, self.backend, self.max_num_neighbors, "data.pos"
        )
        return data

    def __repr__(self) -> str:
        cap = self.max_num_neighbors
        extra = "" if cap is None else f", max_num_neighbors={cap}"
        return f"{type(self).__name__}(radius={self.radius}, backend={self.backend}{extra})"
