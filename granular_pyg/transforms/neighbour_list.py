"""Verlet-style reuse of the particle radius graph over the steps of a rollout.

A fresh radius graph each step costs a tree search over every particle. :class:`NeighbourList`
searches once with ``radius + skin``, keeps the candidate pairs, and at each later step only
tests those pairs against ``radius`` at the current positions. Each particle has a reference
position (where it was when its pairs were last searched). The list is exact while every
particle stays within ``skin / 2`` of its reference: a pair that is not a candidate was at
least ``radius + skin`` apart at the references, so it is still at least ``radius`` apart.

A learned simulator takes steps hundreds of DEM steps long, so in a discharging hopper some
particles (the falling ones) leave their skin every step while most barely move. Only those
*movers* are searched again (on the CPU): their references are reset, their pairs are dropped
and searched anew from their references against everyone's, and merged into the sorted list.
When too many particles move for that (more than ``FULL_SEARCH_FRACTION``), reuse cannot pay
and the list steps aside: it returns plain radius graphs at ``radius`` (no skin, the cheapest
search) and comes back with a skinned search once the particles move less than ``skin / 2``
per step again (fewer than half that fraction). Particles that leave are dropped from the list
without a search.

Each step only tests the pairs whose fate is open: a pair less than ``radius - skin`` apart at
the references is within ``radius`` for as long as the list is exact, so it is kept untested,
and only the shell between ``radius - skin`` and ``radius + skin`` is measured.

The edges are the same, in the same order, as :func:`~granular_pyg.transforms.radius_graph`'s
(tested), because both apply the same exact test to a pair list sorted by (target, source).
"""

from __future__ import annotations

import numpy as np
import torch

from granular_pyg.errors import InputError, check_tensor
from granular_pyg.transforms.radius_graph import (
    _SLACK_ULPS,
    _checked_radius,
    _columns,
    _radius_graph,
    _split_keys,
    _sq_dist,
    _within,
)

__all__ = ["NeighbourList"]

#: Above this fraction of movers a full search is cheaper than a partial one.
FULL_SEARCH_FRACTION = 0.3


class NeighbourList:
    """The radius graph of a moving particle set, searched again only where needed.

    Args:
        radius: cut-off distance (m).
        skin: extra search distance (m); a larger skin searches less often but tests more
            candidate pairs each step.
        backend: radius-graph backend of the full searches (see ``radius_graph``).

    Attributes:
        builds: full searches with the skin so far.
        refreshes: partial searches (movers only) so far.
        plain: plain radius graphs (no skin) returned while reuse could not pay.
        calls: graphs returned so far.
    """

    def __init__(self, radius: float, skin: float, backend: str = "auto") -> None:
        self.radius = _checked_radius(radius)
        if not (skin > 0 and np.isfinite(skin)):
            raise InputError(f"skin: expected a positive distance (m), got {skin}")
        self.skin, self.backend = float(skin), backend
        self.builds = self.refreshes = self.plain = self.calls = 0
        self._ids: torch.Tensor | None = None  # [N] particle ids of the cached rows
        self._ref: torch.Tensor | None = None  # [N, 3] reference positions
        self._pairs: torch.Tensor | None = None  # [2, C] candidate (source, target), sorted
        self._sure: np.ndarray | None = None  # [C] bool: within radius while the list is exact
        self._shell: np.ndarray | None = None  # [S] indices of the other candidates
        self._shell_pairs: np.ndarray | None = None  # [2, S] their (source, target)
        self._stepped_aside = False  # plain graphs; _ref holds the last call's positions

    def __call__(self, pos: torch.Tensor, ids: torch.Tensor | None = None) -> torch.Tensor:
        """``edge_index [2, E]`` of ``pos [N, 3]`` (m), as ``radius_graph(pos, radius)``.

        Args:
            pos: positions of the present particles (m), float32 or float64.
            ids: ``[N]`` int64 stable particle ids, increasing (e.g. the indices of the present
                particles in the full set); lets the list follow particles that leave. None:
                ``arange(N)`` (then the particle set must not change between calls).
        """
        check_tensor("pos", pos, (None, 3))
        n = pos.shape[0]
        ids = torch.arange(n, device=pos.device) if ids is None else ids.to(pos.device)
        if ids.shape != (n,):
            raise InputError(f"ids: expected shape [{n}], got {list(ids.shape)}")
        self.calls += 1
        pos = pos.detach()
        limit = 0.5 * self.skin - 1e-6 * (self.radius + self.skin)  # round-off cannot matter
        known = self._follow(ids)
        moved = None
        if known:
            moved = torch.linalg.vector_norm((pos - self._ref).double(), dim=1) > limit
        if self._stepped_aside:
            if not known or int(moved.sum()) > 0.5 * FULL_SEARCH_FRACTION * n:
                return self._plain(pos, ids)  # still moving too much for a skin to pay
            self._search(pos, ids)
        elif not known:
            self._search(pos, ids)
        else:
            movers = int(moved.sum())
            if movers > FULL_SEARCH_FRACTION * n:
                return self._plain(pos, ids)
            if movers and pos.device.type != "cpu":
                self._search(pos, ids)
            elif movers:
                self._refresh(pos, moved.numpy())
        if pos.device.type == "cpu":  # numpy: 4-5x faster gathers than torch here
            coords, pairs = pos.numpy(), self._pairs.numpy()
            keep = self._sure.copy()
            shell = self._shell_pairs
            keep[self._shell] = _within(
                _columns(coords), shell[1], shell[0], coords.dtype.type(self.radius**2)
            )
            return torch.from_numpy(pairs.compress(keep, axis=1))
        src, dst = self._pairs
        keep = _sq_dist(pos, dst, src) < torch.tensor(self.radius**2, dtype=pos.dtype)
        return self._pairs[:, keep]

    def _plain(self, pos: torch.Tensor, ids: torch.Tensor) -> torch.Tensor:
        """A plain radius graph; remember the positions to measure the next step's moves."""
        self.plain += 1
        self._stepped_aside = True
        self._ref, self._ids, self._pairs = pos.clone(), ids.clone(), None
        return _radius_graph(pos, self.radius, self.backend, None, "pos")

    def _classify(self) -> None:
        """Split the candidates into sure pairs (closer than ``radius - skin`` at the
        references) and the shell whose distance each step must measure (CPU)."""
        if self._pairs.device.type != "cpu":
            return
        pairs = self._pairs.numpy()
        inner = max(self.radius - self.skin, 0.0)
        ref = _columns(self._ref.double().numpy())  # float64: the exact reference distances
        self._set_sure(_within(ref, pairs[1], pairs[0], np.float64(inner * inner)))

    def _set_sure(self, sure: np.ndarray) -> None:
        self._sure = sure
        self._shell = np.flatnonzero(~sure)
        self._shell_pairs = np.ascontiguousarray(self._pairs.numpy()[:, self._shell])

    def _follow(self, ids: torch.Tensor) -> bool:
        """Restrict the cache to ``ids`` (a subset of the cached ids); False if impossible."""
        if self._ids is None:
            return False
        if torch.equal(ids, self._ids):
            return True
        if ids.numel() > self._ids.numel():
            return False
        if ids.device.type == "cpu":  # numpy's is ~100x faster on a busy CPU
            row = torch.from_numpy(np.searchsorted(self._ids.numpy(), ids.numpy()))
        else:
            row = torch.searchsorted(self._ids, ids)
        row = row.clamp(max=self._ids.numel() - 1)
        if not torch.equal(self._ids[row], ids):
            return False  # new particles: search again
        if self._pairs is not None and ids.device.type == "cpu":
            # numpy: torch's gather and .all(0) over the pairs took 20-60 ms on a busy core
            new_index = np.full(self._ids.numel(), -1, dtype=np.int64)
            new_index[row.numpy()] = np.arange(ids.numel())
            pairs = new_index[self._pairs.numpy()]
            stay = (pairs[0] >= 0) & (pairs[1] >= 0)
            self._pairs = torch.from_numpy(pairs.compress(stay, axis=1))  # still sorted
            if self._sure is not None:
                self._set_sure(self._sure[stay])
        elif self._pairs is not None:
            new_index = torch.full((self._ids.numel(),), -1, dtype=torch.long, device=ids.device)
            new_index[row] = torch.arange(ids.numel(), device=ids.device)
            pairs = new_index[self._pairs]
            self._pairs = pairs[:, (pairs >= 0).all(0)]  # a monotone relabel keeps the order
        self._ref, self._ids = self._ref[row], ids
        return True

    def _search(self, pos: torch.Tensor, ids: torch.Tensor) -> None:
        self.builds += 1
        self._pairs = _radius_graph(pos, self.radius + self.skin, self.backend, None, "pos")
        self._ref, self._ids = pos.clone(), ids.clone()
        self._stepped_aside = False
        self._classify()

    def _refresh(self, pos: torch.Tensor, moved: np.ndarray) -> None:
        """Reset the movers' references and search their pairs again (CPU)."""
        from scipy.spatial import cKDTree

        self.refreshes += 1
        self._ref[torch.from_numpy(moved)] = pos[torch.from_numpy(moved)]
        ref = self._ref.double().numpy()
        pairs = self._pairs.numpy()
        kept = pairs.compress(~(moved[pairs[0]] | moved[pairs[1]]), axis=1)
        movers = np.flatnonzero(moved)
        search = (self.radius + self.skin) * (1.0 + _SLACK_ULPS * np.finfo(np.float32).eps)
        found = cKDTree(ref[movers]).sparse_distance_matrix(
            cKDTree(ref), search, output_type="ndarray"
        )
        target, source = movers[found["i"]], found["j"].astype(np.int64)
        real = target != source
        target, source = target[real], source[real]
        # Mover-mover pairs come from both sides; a mover-other pair needs its reverse too.
        other = ~moved[source]
        target, source = (
            np.concatenate([target, source[other]]),
            np.concatenate([source, target[other]]),
        )
        keys = np.sort((target << 32) | source)
        old = (kept[1] << 32) | kept[0]
        self._pairs = _split_keys(np.insert(old, np.searchsorted(old, keys), keys))
        self._classify()
