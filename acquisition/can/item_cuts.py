"""How the CAN decoder cuts its output into stream items.

Samples every channel of a group lost become index jumps (:func:`split_on_holes`); items
are cut on a grid of data time (:func:`cut_samples`, :func:`cut_edges`) so that the
decoder can give them out chunk by chunk, samples and edges of a chunk together, however
large the batch of frames it was fed.
"""

from __future__ import annotations

import itertools

import numpy as np

from acquisition.stream import EdgeBlock, SampleBlock


def split_on_holes(group: str, i0: int, data: np.ndarray) -> list[SampleBlock]:
    """Blocks of ``data`` without the samples every channel lost (those become index jumps)."""
    hole = np.all(np.isnan(data), axis=0)
    if not hole.any():
        return [SampleBlock(group, i0, data)]
    edges = np.flatnonzero(np.diff(np.concatenate([[1], hole.astype(np.int8), [1]])))
    out = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        out.append(SampleBlock(group, i0 + int(a), data[:, a:b]))
    return out


def cut_samples(blk: SampleBlock, step: int) -> list[SampleBlock]:
    """``blk`` cut at the sample indices that are multiples of ``step``."""
    a, b = blk.first_index, blk.first_index + blk.n_samples
    cuts = list(range((a // step + 1) * step, b, step))
    if not cuts:
        return [blk]
    bounds = [a, *cuts, b]
    return [
        SampleBlock(blk.group, i0, blk.data[:, i0 - a : i1 - a])
        for i0, i1 in itertools.pairwise(bounds)
    ]


def cut_edges(eb: EdgeBlock, chunk_s: float) -> list[tuple[int, EdgeBlock]]:
    """``eb`` cut at the multiples of ``chunk_s``, each piece with its chunk number."""
    k = np.floor(eb.times_s / chunk_s).astype(np.int64)
    if k[0] == k[-1]:
        return [(int(k[0]), eb)]
    starts = np.flatnonzero(np.diff(np.concatenate([[k[0] - 1], k])))
    ends = np.append(starts[1:], k.size)
    return [
        (int(k[i0]), EdgeBlock(eb.channel, eb.times_s[i0:i1]))
        for i0, i1 in zip(starts.tolist(), ends.tolist(), strict=True)
    ]
