"""A DBoW2 vocabulary of ORB descriptors, built here (hierarchical k-means), in the text format ORB-SLAM loads.

Text format (what ``TemplatedVocabulary::loadFromTextFile`` of ORB-SLAM2/3 parses)::

    k L scoring weighting                  header: branching, depth, 0 = L1 scoring, 0 = TF-IDF weighting
    parent is_leaf d0 d1 ... d31 weight    one line per node but the root, breadth-first (node ids 1, 2, ...),
    ...                                    d = the 32 descriptor bytes in decimal; no trailing newline (the loader
                                           would read an empty line as one more node)

The tree: hierarchical k-means with the Hamming distance, k-means++ seeding, majority-bit centroids (a bit is set
when at least half of the cluster's descriptors have it). A node with k or fewer distinct descriptors gets one child
per descriptor. Every branch is padded to depth L with single-child nodes carrying the same descriptor: ORB-SLAM
descends a fixed number of levels (its FeatureVector is taken ``levelsup`` levels above the leaves) and reads
undefined node ids in a shorter branch. Leaf weights are TF-IDF's inverse document frequency ``ln(N / N_i)`` over
the training images (``N_i`` = images with a descriptor assigned to leaf i); inner nodes weigh 0.

Deterministic: every node's clustering draws from a generator seeded by (seed, node id).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DESCRIPTOR_BYTES = 32


@dataclass(frozen=True)
class Vocabulary:
    """A vocabulary tree in breadth-first node order (node 0 = root, not written to the file).

    Attributes:
        k: branching factor; levels: depth L (leaves are at depth L).
        parent: int64 (n_nodes,) parent id of every node (-1 for the root).
        is_leaf: bool (n_nodes,).
        descriptors: uint8 (n_nodes, 32) node centroids (the root's is zeros).
        weights: float64 (n_nodes,) IDF weight of the leaves, 0 elsewhere.
    """

    k: int
    levels: int
    parent: np.ndarray
    is_leaf: np.ndarray
    descriptors: np.ndarray
    weights: np.ndarray

    @property
    def n_words(self) -> int:
        return int(self.is_leaf.sum())

    def depth(self) -> np.ndarray:
        """int (n_nodes,) depth of every node (root 0)."""
        d = np.zeros(len(self.parent), np.int64)
        for i in range(1, len(self.parent)):  # breadth-first: parents come first
            d[i] = d[self.parent[i]] + 1
        return d


def hamming_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamming distances between every row of ``a`` (n, 32) and of ``b`` (m, 32), uint8 -> int32 (n, m)."""
    a64 = np.ascontiguousarray(a).view(np.uint64)
    b64 = np.ascontiguousarray(b).view(np.uint64)
    x = a64[:, None, :] ^ b64[None, :, :]
    if hasattr(np, "bitwise_count"):
        return np.bitwise_count(x).sum(axis=-1, dtype=np.int32)
    bytes_ = x.view(np.uint8)
    lut = np.array([bin(i).count("1") for i in range(256)], np.uint8)
    return lut[bytes_].sum(axis=-1, dtype=np.int32)


def _nearest(desc: np.ndarray, centres: np.ndarray, chunk: int = 65536) -> tuple[np.ndarray, np.ndarray]:
    labels = np.empty(len(desc), np.int64)
    dist = np.empty(len(desc), np.int32)
    for s in range(0, len(desc), chunk):
        d = hamming_matrix(desc[s:s + chunk], centres)
        labels[s:s + chunk] = np.argmin(d, axis=1)
        dist[s:s + chunk] = d[np.arange(len(d)), labels[s:s + chunk]]
    return labels, dist


def majority_centroid(desc: np.ndarray) -> np.ndarray:
    """uint8 (32,) descriptor whose bit is set where at least half of ``desc`` (n, 32) have it."""
    bits = np.unpackbits(desc, axis=1).sum(axis=0, dtype=np.int64)
    return np.packbits(2 * bits >= len(desc)).astype(np.uint8)


def _centroids(bits: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    order = np.argsort(labels, kind="stable")
    counts = np.bincount(labels, minlength=k)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    sums = np.add.reduceat(bits[order], starts, axis=0, dtype=np.int32)
    counts = counts[:, None]
    return np.packbits(2 * sums >= counts, axis=1).astype(np.uint8)


def kmeans_hamming(desc: np.ndarray, k: int, rng: np.random.Generator, max_iter: int = 20) -> np.ndarray:
    """Cluster labels int64 (n,) of binary descriptors ``desc`` uint8 (n, 32) into at most ``k`` clusters.

    k-means++ seeding (next centre drawn with probability proportional to the squared distance to the nearest
    chosen centre), then Lloyd iterations with majority-bit centroids until the labels stop changing (at most
    ``max_iter``). Empty clusters are dropped; labels are renumbered 0..k'-1 in order of first centre.
    """
    n = len(desc)
    centres = [int(rng.integers(n))]
    d_min = hamming_matrix(desc, desc[centres[0]][None])[:, 0].astype(np.float64)
    while len(centres) < k:
        p = d_min ** 2
        total = p.sum()
        if total <= 0:
            break  # every descriptor equals a chosen centre
        c = int(rng.choice(n, p=p / total))
        centres.append(c)
        d_min = np.minimum(d_min, hamming_matrix(desc, desc[c][None])[:, 0])
    cent = desc[centres].copy()
    bits = np.unpackbits(desc, axis=1)
    labels, _ = _nearest(desc, cent)
    for _ in range(max_iter):
        used = np.unique(labels)
        cent = _centroids(bits, np.searchsorted(used, labels), len(used))
        new, _ = _nearest(desc, cent)
        if np.array_equal(new, np.searchsorted(used, labels)):
            labels = new
            break
        labels = new
    _, labels = np.unique(labels, return_inverse=True)
    return labels.astype(np.int64)


def build_vocabulary(descriptors_per_image: list[np.ndarray], k: int = 10, levels: int = 5, seed: int = 0,
                     max_iter: int = 20) -> Vocabulary:
    """Train a DBoW2 vocabulary on the ORB descriptors of training images.

    Args:
        descriptors_per_image: one uint8 array (n_i, 32) per training image (the images define the IDF weights).
        k: branching factor (ORB-SLAM accepts 2..20); levels: depth L (1..10).
        seed: the only source of randomness; same inputs and seed -> the same tree, bit for bit.
    """
    if not 2 <= k <= 20 or not 1 <= levels <= 10:
        raise ValueError(f"k must be in 2..20 and levels in 1..10 (got k={k}, levels={levels})")
    mats = [np.asarray(d, np.uint8).reshape(-1, DESCRIPTOR_BYTES) for d in descriptors_per_image]
    if not mats or sum(len(m) for m in mats) == 0:
        raise ValueError("no training descriptors")
    desc = np.concatenate(mats)
    image_of = np.concatenate([np.full(len(m), i, np.int64) for i, m in enumerate(mats)])
    parent = [-1]
    depth = [0]
    node_desc = [np.zeros(DESCRIPTOR_BYTES, np.uint8)]
    members: list[np.ndarray] = [np.arange(len(desc))]
    leaf_members: dict[int, np.ndarray] = {}
    frontier = [0]
    for level in range(1, levels + 1):
        next_frontier = []
        for nid in frontier:
            idx = members[nid]
            sub = desc[idx]
            uniq = np.unique(sub, axis=0) if len(sub) <= k else None
            if uniq is not None:  # one child per distinct descriptor (one child: a padding node)
                groups = [idx[(sub == u).all(axis=1)] for u in uniq]
                cents = list(uniq)
            else:
                rng = np.random.default_rng([seed, nid])
                labels = kmeans_hamming(sub, k, rng, max_iter)
                groups = [idx[labels == c] for c in range(labels.max() + 1)]
                cents = [majority_centroid(desc[g]) for g in groups]
            for g, c in zip(groups, cents):
                cid = len(parent)
                parent.append(nid)
                depth.append(level)
                node_desc.append(np.asarray(c, np.uint8))
                members.append(g)
                next_frontier.append(cid)
                if level == levels:
                    leaf_members[cid] = g
            members[nid] = np.empty(0, np.int64)  # free
        frontier = next_frontier
    n_nodes = len(parent)
    is_leaf = np.zeros(n_nodes, bool)
    weights = np.zeros(n_nodes)
    n_images = len(mats)
    for cid, g in leaf_members.items():
        is_leaf[cid] = True
        n_i = len(np.unique(image_of[g]))
        weights[cid] = float(np.log(n_images / n_i)) if n_i > 0 else 0.0
    return Vocabulary(k, levels, np.array(parent, np.int64), is_leaf, np.stack(node_desc), weights)


def vocabulary_text(vocab: Vocabulary) -> str:
    """The DBoW2 text file of ``vocab`` (header, one line per non-root node breadth-first, no trailing newline)."""
    lines = [f"{vocab.k} {vocab.levels} 0 0"]
    for i in range(1, len(vocab.parent)):
        d = " ".join(str(int(b)) for b in vocab.descriptors[i])
        lines.append(f"{int(vocab.parent[i])} {int(vocab.is_leaf[i])} {d} {vocab.weights[i]:.6g}")
    return "\n".join(lines)


def parse_vocabulary_text(text: str) -> Vocabulary:
    """Inverse of :func:`vocabulary_text` (for checks); raises ValueError on a malformed file."""
    lines = text.split("\n")
    head = lines[0].split()
    if len(head) != 4:
        raise ValueError("bad vocabulary header (expected 'k L scoring weighting')")
    k, levels = int(head[0]), int(head[1])
    parent, leaf, desc, w = [-1], [False], [np.zeros(DESCRIPTOR_BYTES, np.uint8)], [0.0]
    for n, line in enumerate(lines[1:], start=2):
        tok = line.split()
        if len(tok) != 3 + DESCRIPTOR_BYTES:
            raise ValueError(f"vocabulary line {n}: {len(tok)} fields, expected {3 + DESCRIPTOR_BYTES}")
        p = int(tok[0])
        if not 0 <= p < len(parent):
            raise ValueError(f"vocabulary line {n}: parent {p} not defined before")
        parent.append(p)
        leaf.append(tok[1] != "0")
        desc.append(np.array([int(x) for x in tok[2:2 + DESCRIPTOR_BYTES]], np.uint8))
        w.append(float(tok[-1]))
    return Vocabulary(k, levels, np.array(parent), np.array(leaf), np.stack(desc), np.array(w))
