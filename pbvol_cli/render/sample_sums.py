"""Per-pixel sums over samples that merge exactly: a render of samples A..B-1 and renders of sub-ranges combined
give the same floating-point sum, bit for bit.

Floating-point addition is not associative, so a sum must be formed in one canonical order whatever the split. The
samples' images are combined as a binary tree over sample indices: a node covers an aligned range [k 2^j,
(k + 1) 2^j) and its sum is (left child's + right child's); a leaf is one sample's image (one path per pixel: no
addition). A range [A, B) is held as its maximal aligned nodes (SampleSums.nodes); merging ranges pools their nodes
and recombines siblings; the total is the nodes' sums added left to right. A render of [0, N) and a merge of
parts that tile [0, N) therefore do the same additions in the same order.
"""

from __future__ import annotations

import numpy as np


class SampleSums:
    """Nodes (lo, hi, sum) of an aligned binary tree over sample indices, left to right (sum: float64 array)."""

    def __init__(self):
        self.nodes: list[tuple[int, int, np.ndarray]] = []

    def push(self, lo: int, hi: int, value: np.ndarray):
        """Append the node [lo, hi) (right after the last one), combining siblings as they complete."""
        if self.nodes and self.nodes[-1][1] != lo:
            raise ValueError(f"samples {lo}:{hi} do not follow {self.nodes[-1][0]}:{self.nodes[-1][1]}")
        self.nodes.append((lo, hi, value))
        while len(self.nodes) >= 2:
            (l0, h0, a), (l1, h1, b) = self.nodes[-2], self.nodes[-1]
            size = h0 - l0
            if h1 - l1 != size or l0 % (2 * size) != 0:
                break
            self.nodes[-2:] = [(l0, h1, a + b)]

    def add_sample(self, index: int, image: np.ndarray):
        self.push(index, index + 1, np.array(image, dtype=np.float64))

    @property
    def range(self) -> tuple[int, int]:
        return (self.nodes[0][0], self.nodes[-1][1]) if self.nodes else (0, 0)

    def total(self) -> np.ndarray:
        """The sum over the whole range: the nodes added left to right."""
        out = self.nodes[0][2].copy()
        for _, _, v in self.nodes[1:]:
            out = out + v
        return out

    @classmethod
    def merged(cls, parts: list["SampleSums"]) -> "SampleSums":
        """The sums of parts whose ranges tile one range (in any order): ValueError where they overlap or leave a
        gap."""
        nodes = sorted((n for p in parts for n in p.nodes), key=lambda n: n[0])
        out = cls()
        for lo, hi, v in nodes:
            out.push(lo, hi, v)
        return out

    def arrays(self) -> dict:
        return {"lo": np.array([n[0] for n in self.nodes], np.int64), "hi": np.array([n[1] for n in self.nodes],
                                                                                       np.int64),
                "sums": np.stack([n[2] for n in self.nodes]) if self.nodes else np.zeros((0,))}

    @classmethod
    def from_arrays(cls, d) -> "SampleSums":
        out = cls()
        out.nodes = [(int(lo), int(hi), np.asarray(s, np.float64)) for lo, hi, s in zip(d["lo"], d["hi"], d["sums"])]
        return out


def layer_means(sums: dict, count: int, shape) -> dict:
    """{layer: its SampleSums' total / count, shaped}: the one place a render's layers (and, added in the dict's
    order, its image) come from their sums, in a render and in pbvol merge."""
    return {name: (s.total() / count).reshape(shape) for name, s in sums.items()}
