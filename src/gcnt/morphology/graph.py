"""Graph features of a limb tree, from its parent array alone (numpy only).

Every function takes ``parents`` (int array, ``parents[0] == -1`` for the torso, limbs in
depth-first pre-order) or the adjacency derived from it, so that the same code serves SMPENV and
UNIMAL robots and the property tests' random trees.
"""

from __future__ import annotations

import hashlib
import struct
from collections import deque
from dataclasses import dataclass

import numpy as np

#: Marker for "no path / padding" in uint8 distance matrices.
DIST_PAD = 255
#: Default number of WL refinement rounds (the paper fixes a count but does not give it).
WL_ROUNDS = 3
#: Default size of the WL colour-count vector (colours are hashed into this many buckets).
WL_BUCKETS = 64


def check_tree(parents: np.ndarray, name: str = "robot") -> None:
    """Raise ValueError unless ``parents`` is a pre-ordered tree rooted at index 0."""
    parents = np.asarray(parents)
    if parents.ndim != 1 or len(parents) == 0:
        raise ValueError(f"{name}: parent array must be 1-d and non-empty")
    if parents[0] != -1:
        raise ValueError(f"{name}: limb 0 (torso) must be the root (parent -1)")
    for i, p in enumerate(parents[1:], start=1):
        if not 0 <= p < i:
            raise ValueError(
                f"{name}: limb {i} has parent {p}; limbs must be in depth-first pre-order "
                "with every parent before its children (a cyclic or disconnected body graph?)"
            )


def children_lists(parents: np.ndarray) -> list[list[int]]:
    kids: list[list[int]] = [[] for _ in parents]
    for i, p in enumerate(parents):
        if p >= 0:
            kids[p].append(i)
    return kids


def adjacency(parents: np.ndarray) -> np.ndarray:
    """Undirected body-parent adjacency, bool [K, K], no self loops."""
    k = len(parents)
    adj = np.zeros((k, k), dtype=bool)
    child = np.nonzero(parents >= 0)[0]
    adj[child, parents[child]] = True
    adj[parents[child], child] = True
    return adj


def hop_distances(adj: np.ndarray) -> np.ndarray:
    """All-pairs shortest-path hop counts by BFS (int64 [K, K]; -1 if unreachable)."""
    k = len(adj)
    nbrs = [np.nonzero(row)[0] for row in adj]
    dist = np.full((k, k), -1, dtype=np.int64)
    for s in range(k):
        dist[s, s] = 0
        queue = deque([s])
        while queue:
            u = queue.popleft()
            for v in nbrs[u]:
                if dist[s, v] < 0:
                    dist[s, v] = dist[s, u] + 1
                    queue.append(v)
    return dist


def stable_hash(*parts: int | tuple[int, ...]) -> int:
    """A 63-bit hash of integers that is the same in every process and on every machine.

    Python's ``hash`` is salted per process, so it cannot be used for WL colours that must match
    between training and a zero-shot evaluation run.
    """
    flat: list[int] = []
    for p in parts:
        flat.extend(p if isinstance(p, tuple) else (p,))
    data = struct.pack(f"<{len(flat)}q", *flat)
    return int.from_bytes(hashlib.blake2b(data, digest_size=8).digest(), "little") >> 1


def wl_colours(types: np.ndarray, adj: np.ndarray, rounds: int = WL_ROUNDS) -> np.ndarray:
    """Weisfeiler-Lehman colours, int64 [rounds + 1, K]; row 0 is the limb-type colouring.

    New colour = hash(round, own colour, sorted multiset of neighbour colours). The round number
    is hashed in so that colours of different rounds do not alias.
    """
    nbrs = [np.nonzero(row)[0] for row in adj]
    cols = np.empty((rounds + 1, len(types)), dtype=np.int64)
    cols[0] = [stable_hash(0, int(t)) for t in types]
    for r in range(1, rounds + 1):
        prev = cols[r - 1]
        cols[r] = [
            stable_hash(r, int(prev[v]), tuple(sorted(int(c) for c in prev[nbrs[v]])))
            for v in range(len(types))
        ]
    return cols


def wl_counts(
    types: np.ndarray, adj: np.ndarray, rounds: int = WL_ROUNDS, buckets: int = WL_BUCKETS
) -> np.ndarray:
    """How often each (bucketed) colour occurs over all WL rounds: float32 [buckets]."""
    cols = wl_colours(types, adj, rounds)
    return np.bincount((cols % buckets).ravel(), minlength=buckets).astype(np.float32)


def traversal_indices(parents: np.ndarray) -> np.ndarray:
    """SWAT's three traversal positions of every limb, int64 [K, 3].

    Column 0: depth-first pre-order index of the limb tree (= limb index here). Columns 1, 2:
    in-order and post-order index in the left-child right-sibling binary tree of the limb tree
    (left = first child, right = next sibling).
    """
    k = len(parents)
    kids = children_lists(parents)
    left = [c[0] if c else -1 for c in kids]
    right = [-1] * k
    for c in kids:
        for a, b in zip(c, c[1:], strict=False):
            right[a] = b
    out = np.zeros((k, 3), dtype=np.int64)
    out[:, 0] = np.arange(k)
    # Iterative traversals (robots can be deep enough that recursion is a needless risk).
    inorder: list[int] = []
    stack: list[int] = []
    node = 0
    while stack or node >= 0:
        while node >= 0:
            stack.append(node)
            node = left[node]
        node = stack.pop()
        inorder.append(node)
        node = right[node]
    postorder: list[int] = []
    stack2 = [0]
    while stack2:
        n = stack2.pop()
        postorder.append(n)
        stack2.extend(c for c in (left[n], right[n]) if c >= 0)
    postorder.reverse()
    out[inorder, 1] = np.arange(k)
    out[postorder, 2] = np.arange(k)
    return out


def personalized_pagerank(adj: np.ndarray, damping: float = 0.9) -> np.ndarray:
    """Row i: stationary visit probabilities of a random walk that restarts at limb i.

    PPR = (1 - d) (I - d T)^-1 with T the row-stochastic transition matrix D^-1 A. A limb with no
    neighbours (a torso-only robot) keeps the walk where it is, so every row sums to 1.
    """
    k = len(adj)
    a = adj.astype(np.float64)
    deg = a.sum(1, keepdims=True)
    t = np.divide(a, deg, out=np.zeros_like(a), where=deg > 0)
    isolated = deg[:, 0] == 0
    t[isolated, isolated] = 1.0
    return ((1 - damping) * np.linalg.inv(np.eye(k) - damping * t)).astype(np.float32)


def normalized_laplacian(adj: np.ndarray) -> np.ndarray:
    """I - D^-½ A D^-½ (isolated nodes get a zero row off the diagonal)."""
    a = adj.astype(np.float64)
    deg = a.sum(1)
    d = np.divide(1.0, np.sqrt(deg), out=np.zeros_like(deg), where=deg > 0)
    return (np.eye(len(a)) - d[:, None] * a * d[None, :]).astype(np.float32)


@dataclass(frozen=True)
class RobotGraph:
    """All static graph features of one robot, unpadded numpy arrays."""

    adj: np.ndarray  # bool [K, K]
    dist: np.ndarray  # int64 [K, K]
    wl: np.ndarray  # float32 [W]
    traversal: np.ndarray  # int64 [K, 3]
    ppr: np.ndarray  # float32 [K, K]
    laplacian: np.ndarray  # float32 [K, K]

    @classmethod
    def from_tree(
        cls,
        parents: np.ndarray,
        types: np.ndarray,
        wl_rounds: int = WL_ROUNDS,
        wl_buckets: int = WL_BUCKETS,
    ) -> RobotGraph:
        parents = np.asarray(parents, dtype=np.int64)
        check_tree(parents)
        adj = adjacency(parents)
        return cls(
            adj=adj,
            dist=hop_distances(adj),
            wl=wl_counts(np.asarray(types), adj, wl_rounds, wl_buckets),
            traversal=traversal_indices(parents),
            ppr=personalized_pagerank(adj),
            laplacian=normalized_laplacian(adj),
        )
