"""Is a file a usable DBoW2 vocabulary? Checked before any ORB-SLAM3 run (one clear line when it is not).

ORB-SLAM3's text loader (``TemplatedVocabulary::loadFromTextFile``) checks only the header's ranges: a file holding
just ``10 5 0 0`` loads ("Vocabulary loaded!") and every run then loses track on its first frames, so a benchmark
would report every AE method as failing. :func:`check_vocabulary` reads the whole file (numpy's text parser: about
a second for ORB-SLAM's 145 MB ``ORBvoc.txt``, milliseconds for the project's own) and refuses:

* a binary or compressed form (gzip, tar, zip, bzip2, xz, DBoW2/DBoW3 binary: the ``pyorbslam3`` binding loads text
  only, so these are named with the fix: unpack to the ``.txt``);
* a header that is not ``k L scoring weighting`` with the loader's ranges (k 2..20, L 1..10, scoring 0..5,
  weighting 0..3);
* no node lines (header only), a line that is not ``parent is_leaf d0..d31 weight`` (35 numbers), descriptor bytes
  outside 0..255, a negative or non-finite weight;
* a tree inconsistent with its header: more nodes than the full tree (``sum_{l=1..L} k^l``), a node whose parent is
  not an earlier inner node, more than k children, a node deeper than L, no node at depth L, an inner node without
  children (a file cut at a line boundary), no word (leaf).

A file cut mid-line fails the 35-number rule. Trailing empty lines are ignored here. What the loader then does with
the file is the set-up check's business (:mod:`bracketry_emulator.slam.setup_check`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bracketry_base.errors import BracketryError

DESCRIPTOR_BYTES = 32
FIELDS = 3 + DESCRIPTOR_BYTES  # parent, is_leaf, 32 bytes, weight
#: leading bytes of binary / compressed forms -> what they are
_MAGIC = ((b"\x1f\x8b", "gzip-compressed"), (b"BZh", "bzip2-compressed"), (b"\xfd7zXZ", "xz-compressed"),
          (b"PK\x03\x04", "a zip archive"), (b"\x28\xb5\x2f\xfd", "zstd-compressed"))


class VocabularyError(BracketryError):
    """The vocabulary file is not a usable DBoW2 text vocabulary (one line naming the file and the reason)."""


@dataclass(frozen=True)
class VocabularySummary:
    """What the check found: branching ``k``, depth ``levels``, ``n_nodes`` (without the root), ``n_words``."""

    k: int
    levels: int
    n_nodes: int
    n_words: int


def full_tree_nodes(k: int, levels: int) -> int:
    """Nodes of a full tree without the root: sum_{l=1..L} k^l."""
    return sum(k ** level for level in range(1, levels + 1))


def _binary_kind(head: bytes) -> str | None:
    for magic, what in _MAGIC:
        if head.startswith(magic):
            return what
    if len(head) >= 262 and head[257:262] == b"ustar":
        return "a tar archive"
    if b"\x00" in head[:4096]:
        return "binary (not DBoW2 text)"
    return None


def check_vocabulary(path: str | Path) -> VocabularySummary:
    """Check a DBoW2 text vocabulary (see the module docstring); raises :class:`VocabularyError` (one line)."""
    p = Path(path)

    def bad(why: str) -> VocabularyError:
        return VocabularyError(f"ORB-SLAM3 vocabulary {p}: {why}")

    try:
        data = p.read_bytes()
    except OSError as exc:
        raise bad(f"cannot be read ({exc.strerror or exc})") from None
    kind = _binary_kind(data[:4096])
    if kind is not None:
        raise bad(f"{kind}; pyorbslam3 loads the DBoW2 text form only (unpack it, e.g. ORBvoc.txt.tar.gz -> "
                  "ORBvoc.txt)")
    first_nl = data.find(b"\n")
    header = (data if first_nl < 0 else data[:first_nl]).decode("ascii", "replace").split()
    try:
        k, levels, scoring, weighting = (int(x) for x in header)
    except ValueError:
        raise bad("not a DBoW2 text vocabulary (its first line must be 'k L scoring weighting', four integers)"
                  ) from None
    if not (2 <= k <= 20 and 1 <= levels <= 10 and 0 <= scoring <= 5 and 0 <= weighting <= 3):
        raise bad(f"bad header '{' '.join(header)}' (k 2..20, L 1..10, scoring 0..5, weighting 0..3)")
    body = b"" if first_nl < 0 else data[first_nl + 1:].rstrip(b"\n")
    if not body.strip():
        raise bad(f"holds only its header '{' '.join(header)}', no node (a k={k}, L={levels} tree has up to "
                  f"{full_tree_nodes(k, levels)} nodes)")
    n_lines = body.count(b"\n") + 1
    if n_lines > full_tree_nodes(k, levels):
        raise bad(f"{n_lines} node lines, more than a full k={k}, L={levels} tree has ({full_tree_nodes(k, levels)})")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unparsable text: numpy stops and warns (later: raises); the count tells
        try:
            values = np.fromstring(body, dtype=np.float64, sep=" ")
        except ValueError:
            values = np.empty(0)
    if len(values) != n_lines * FIELDS:
        raise bad(f"{n_lines} node lines but {len(values)} numbers where {n_lines * FIELDS} were expected "
                  f"({FIELDS} per line: parent is_leaf d0..d31 weight): truncated or not a vocabulary")
    nodes = values.reshape(n_lines, FIELDS)
    ints = nodes[:, :-1]
    if not np.all(ints == np.round(ints)):
        raise bad("a parent, leaf flag or descriptor byte is not an integer")
    parent = nodes[:, 0].astype(np.int64)
    is_leaf = nodes[:, 1] != 0
    desc = nodes[:, 2:2 + DESCRIPTOR_BYTES]
    weight = nodes[:, -1]
    if desc.min() < 0 or desc.max() > 255:
        raise bad("a descriptor byte is outside 0..255")
    if not np.all(np.isfinite(weight)) or weight.min() < 0:
        raise bad("a word weight is negative or not finite")
    ids = np.arange(1, n_lines + 1)
    if parent.min() < 0 or np.any(parent >= ids):
        line = int(np.argmax((parent < 0) | (parent >= ids))) + 2
        raise bad(f"line {line}: its parent is not a node defined before it (truncated or reordered file)")
    leaf_all = np.concatenate([[False], is_leaf])  # node 0 = the root
    if np.any(leaf_all[parent]):
        raise bad("a word (leaf) has children")
    children = np.bincount(parent, minlength=n_lines + 1)
    if children.max() > k:
        raise bad(f"a node has {int(children.max())} children, more than k={k}")
    depth = np.zeros(n_lines + 1, np.int64)
    for _ in range(levels + 1):  # parents come first: after pass l every node up to depth l has its depth
        depth[1:] = depth[parent] + 1
    if depth.max() > levels:
        raise bad(f"a node is at depth {int(depth.max())}, deeper than L={levels}")
    if depth.max() < levels:
        raise bad(f"no node at depth L={levels} (deepest {int(depth.max())}): truncated")
    inner_without_children = (~leaf_all) & (children == 0)
    inner_without_children[0] = False
    if inner_without_children.any():
        raise bad(f"{int(inner_without_children.sum())} inner node(s) without children: truncated")
    n_words = int(is_leaf.sum())
    if n_words == 0:
        raise bad("no word (leaf node)")
    return VocabularySummary(k, levels, n_lines, n_words)
