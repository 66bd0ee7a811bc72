"""The sets of channels the segment sums are taken for, and the numpy path that takes them.

:func:`dsp.sums.add_sample_sets` cuts the samples into segments and hands them here
(:func:`numpy_sums`, the reference) or to the compiled kernel (:mod:`dsp.kernels`), which
must give the same sums within 1e-12; both give per set the raw sums
(:data:`SetSums`) that :func:`dsp.sums.add_sample_sets` rotates and packs into rows.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dsp.frames import rise_table
from dsp.sum_rows import Row

POWER_STRIDE = 4


@dataclass(frozen=True)
class SumSet:
    """Channels of one group summed with one set of orders (:func:`add_sample_sets`).

    ``tracked`` sets are summed as the tracked channels always were (the zone sums
    from gathered carrier rows: BLAS rounds each layout its own way, and the frames
    stay bit for bit what they were), with the mean square and the clip count.
    A set with ``tracked=False`` is one channel (the spectrum channel): a matrix-vector
    product per segment with the taper applied to the samples, no gather, and neither
    mean square nor clip count (zeros): 1.6x faster for one channel.
    """

    rows: dict[int, Row]  # segment m -> Row, as in add_samples
    x: Sequence[np.ndarray]  # (n_ch, n_i) pieces; (1, n_i) unless tracked
    k2: np.ndarray  # (n_orders,) int64, ascending
    clip_level: float | None = None
    tracked: bool = True


@dataclass(frozen=True)
class Segments:
    """The segments met by one call: ``mu``, first and end sample, zone end (all (seg,),
    segments of each piece in turn), where each piece begins (``cuts``), how many segments
    each piece has, the frame angles ``c`` (rad) and half the taper zone (rad)."""

    mu: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    zone_end: np.ndarray
    cuts: list[int]
    per_piece: list[int]
    c: np.ndarray
    half: float


@dataclass(frozen=True)
class Cut:
    """What the sums of every set on the same samples share (:func:`dsp.sums.cut_samples`):
    the segments, ``phi`` (rad), ``q = omega dt`` (rad) and ``delta`` (rad, from the
    sample's frame angle) (n,), the cosine and sine of ``delta / 2`` in single precision
    (n,) float32 (:func:`base_parts`: the carriers' base ``exp(-i delta / 2)`` is
    ``cos_half - i sin_half``), and on the numpy path the zones' samples and weights
    (:func:`zones`), on the compiled path each zone's falling taper at its samples'
    places (n,) and its sum with ``q`` (seg,) (:func:`dsp.kernels.segment_cuts`). Groups
    on one sample clock get the same cut in a step: it is made once for all of them
    (:mod:`dsp.segments`)."""

    seg: Segments
    phi: np.ndarray
    q: np.ndarray
    delta: np.ndarray
    cos_half: np.ndarray
    sin_half: np.ndarray
    zones: Zones | None = None
    falls: tuple[np.ndarray, np.ndarray] | None = None


# every zone's samples at once: z_len, z_off (seg + 1,), the zones' sample indices z, their
# falling-taper weights fall (sum z_len,), and the weights wa, wd (seg,)
Zones = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def zones(segs: Segments, phi: np.ndarray, q: np.ndarray) -> Zones:
    """The zones' samples, taper weights and the segments' weights ``wa``, ``wd`` (numpy)."""
    mu, starts, ends, zone_end = segs.mu, segs.starts, segs.ends, segs.zone_end
    c, half = segs.c, segs.half
    z_len = zone_end - starts
    z_off = np.zeros(mu.size + 1, dtype=np.int64)
    np.cumsum(z_len, out=z_off[1:])
    z = np.repeat(starts - z_off[:-1], z_len) + np.arange(z_off[-1])  # sample indices
    tw = 2.0 * half
    r = phi[z] - np.repeat(c - half, z_len)
    fall = 1.0 - rise_table(r / tw)
    wd = np.zeros(mu.size)
    has_zone = z_len > 0
    if has_zone.any():
        wd[has_zone] = np.add.reduceat(q[z] * fall, z_off[:-1][has_zone])
    wa = np.add.reduceat(q, starts) if segs.cuts[-1] else np.zeros(mu.size)
    wa[starts == ends] = 0.0  # reduceat gives the next element for an empty segment
    return z_len, z_off, z, fall, wa, wd


# per set: a, d (seg, n_ch, rows), s2 (seg, n_ch), n2 (seg,), clip (seg, n_ch), and the
# rows of the real and imaginary parts of each order
SetSums = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[int], list[int]]


def numpy_sums(
    sets: Sequence[SumSet], cut: Cut, first_index: int
) -> tuple[list[SetSums], np.ndarray, np.ndarray]:
    """Every set's sums and the weights ``wa``, ``wd`` in numpy: the reference."""
    segs = cut.seg
    mu, starts, ends = segs.mu, segs.starts, segs.ends
    cuts, per_piece = segs.cuts, segs.per_piece
    z_len, z_off, z, fall, wa, wd = cut.zones or zones(segs, cut.phi, cut.q)
    carr = carriers(cut.cos_half, cut.sin_half, cut.q, [s.k2 for s in sets])
    out: list[SetSums] = []
    for st, (e, re, im) in zip(sets, carr, strict=True):
        k2, x = st.k2, st.x
        no = k2.size
        n_ch = x[0].shape[0]
        a = np.zeros((mu.size, n_ch, 2 * no))
        d = np.zeros_like(a)
        s2 = np.zeros((mu.size, n_ch))
        n2 = np.zeros(mu.size, dtype=np.int64)
        clip = np.zeros((mu.size, n_ch), bool)
        if st.tracked:
            assert re == list(range(no)), "a tracked set keeps the Re-then-Im row layout"
            # (zone samples, 2 n_orders) in C order: the layout the zone sums were always
            # taken in, and a row gather is 3x faster than e[:, z]
            ezt = e.T[z]
            ezt *= fall[:, None]
            i = 0
            for xp, p0, count in zip(x, cuts[:-1], per_piece, strict=True):
                seg = slice(i, i + count)
                local = zip(
                    (starts[seg] - p0).tolist(), (ends[seg] - p0).tolist(), z_len[seg].tolist(),
                    z_off[seg].tolist(), strict=True,
                )  # fmt: skip
                for s0, s1, zl, zo in local:
                    if s1 > s0:
                        np.matmul(xp[:, s0:s1], e[:, p0 + s0 : p0 + s1].T, out=a[i])
                    if zl:
                        np.matmul(xp[:, s0 : s0 + zl], ezt[zo : zo + zl], out=d[i])
                    i += 1
                s2[seg], n2[seg] = _power(xp, first_index + p0, starts[seg] - p0)
                if st.clip_level is not None:
                    clip[seg] = _clipped(xp, starts[seg] - p0, ends[seg] - p0, st.clip_level)
        else:
            # one channel: e (2 no, n) @ x (n,) per segment; the zone's taper goes on the samples
            x1 = x[0][0] if len(x) == 1 else np.concatenate([xp[0] for xp in x])
            xz = x1[z] * fall
            bounds = zip(
                starts.tolist(), ends.tolist(), z_len.tolist(), z_off[:-1].tolist(), strict=True
            )
            for i, (s0, s1, zl, zo) in enumerate(bounds):
                if s1 > s0:
                    np.matmul(e[:, s0:s1], x1[s0:s1], out=a[i, 0])
                if zl:
                    np.matmul(e[:, s0 : s0 + zl], xz[zo : zo + zl], out=d[i, 0])
        out.append((a, d, s2, n2, clip, re, im))
    return out, wa, wd


def _power(x: np.ndarray, first_index: int, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``sum x^2`` (s, n_ch) and count (s,) over the samples of segments beginning at
    ``starts`` whose grid index is a multiple of POWER_STRIDE (``x``: one piece)."""
    off = (-first_index) % POWER_STRIDE
    sub = x[:, off::POWER_STRIDE]
    sub_starts = (starts - off + POWER_STRIDE - 1) // POWER_STRIDE
    sub_ends = np.append(sub_starts[1:], sub.shape[1])
    n2 = np.maximum(sub_ends - sub_starts, 0)
    s2 = np.zeros((starts.size, x.shape[0]))
    has = np.flatnonzero(n2)
    if has.size:
        s2[has] = np.add.reduceat(np.square(sub), sub_starts[has], axis=1).T
    return s2, n2


def _clipped(x: np.ndarray, starts: np.ndarray, ends: np.ndarray, level: float) -> np.ndarray:
    """Whether a segment of one piece ``x`` holds a sample at or above ``level``: (s, n_ch)."""
    big = np.abs(x) >= level
    clip = np.zeros((starts.size, x.shape[0]), bool)
    full = np.flatnonzero(ends > starts)
    clip[full] = np.logical_or.reduceat(big, starts[full], axis=1).T
    return clip


def base_parts(delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``cos(delta / 2)`` and ``sin(delta / 2)`` in single precision (n,) float32: the base
    ``exp(-i delta / 2) = cos - i sin`` that :func:`carriers` and the compiled kernel
    build on (widened to double there, exactly). The compiled path makes ``delta / 2`` in
    its segment pass (:func:`dsp.fused_segments.segment_cuts`, the same bits) and only
    the cosine and sine here: numpy's SIMD ``cos``/``sin`` round as they always did."""
    return half_parts((0.5 * delta).astype(np.float32))


def half_parts(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``cos(half)``, ``sin(half)`` of single-precision angles (rad): (n,) float32."""
    return np.cos(half), np.sin(half)


def carriers(
    cos_half: np.ndarray, sin_half: np.ndarray, q: np.ndarray, k2s: Sequence[np.ndarray]
) -> list[tuple[np.ndarray, list[int], list[int]]]:
    """``q exp(-i k delta / 2)`` for every ``k`` in each ``k2`` of ``k2s``, from the base
    ``exp(-i delta / 2) = cos_half - i sin_half`` (:func:`base_parts`, float32).

    Returns, per ``k2``, ``(e, re, im)``: ``e`` (rows, n_samples) holds the real part of
    order ``k2[j]`` in row ``re[j]``, its imaginary part in row ``im[j]``. The first ``k2``
    gets rows ``Re`` then ``Im`` (2 n, n_samples), the tracked channels' layout. A later
    ``k2`` that holds all the first's orders (the spectrum channel's) puts its other
    orders after those rows, and the first's array is a view of its top: each carrier
    is written once.

    ``cos`` and ``sin`` of ``delta / 2`` in single precision (vectorised: 15x faster
    than double here, half the carrier cost), then a running product in double
    (each ``k2`` ascending; one product serves them all, so an order's carrier is the
    same whatever else is tracked). The single-precision error, ~1e-7 rad per sample and a
    fixed function of the sample's angle, shows as leakage of about 1e-7 of the
    strongest order into the others (-140 dB; measured on the simulated i3 at
    3000 rpm: 7e-8, against 1e-10 in double): 80 dB below the 60 dB specified,
    and far below any noise a bench has.
    """
    n = q.size
    base = np.empty(n, complex)
    base.real, base.imag = cos_half, np.negative(sin_half)  # widened exactly
    first = k2s[0].tolist()
    n0 = len(first)
    out: list[tuple[np.ndarray, list[int], list[int]]] = []
    writes: list[tuple[np.ndarray, list[int], list[int], list[int]]] = []  # (e, k, re, im)
    sharer = None
    for j, k2 in enumerate(k2s):
        ks = k2.tolist()
        if j and sharer is None and set(first) <= set(ks):
            sharer = j
            top = {k: r for r, k in enumerate(first)}
            extra = [k for k in ks if k not in top]
            below = {k: r for r, k in enumerate(extra)}
            n_e = len(extra)
            re = [top[k] if k in top else 2 * n0 + below[k] for k in ks]
            im = [top[k] + n0 if k in top else 2 * n0 + n_e + below[k] for k in ks]
        else:
            re = list(range(len(ks)))
            im = [len(ks) + r for r in re]
        e = np.empty((2 * len(ks), n))
        out.append((e, re, im))
        writes.append((e, ks, re, im))
    if sharer is not None:
        e = out[sharer][0]
        out[0] = (e[: 2 * n0], out[0][1], out[0][2])
        del writes[0]
    rows: dict[int, list[tuple[np.ndarray, int, int]]] = {}
    for e, ks, re, im in writes:
        for k, r, i in zip(ks, re, im, strict=True):
            rows.setdefault(k, []).append((e, r, i))
    for e, r, i in rows.get(0, []):
        e[r] = q  # order 0: the plain weight
        e[i] = 0.0
    p = base * q
    for k in range(1, max(int(k2.max()) for k2 in k2s) + 1):
        if k > 1:
            p *= base
        for e, r, i in rows.get(k, []):
            e[r] = p.real
            e[i] = p.imag
    return out
