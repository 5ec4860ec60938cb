"""Vector quantisation for compressed splat formats (SOG): 1D codebooks and a k-means palette.

`scalar_codebook(values, size)` -> (codebook ascending, labels): `size` values that minimise the
squared error of the pooled `values`, found by dynamic programming over a 1024-bin histogram
(the optimal 1D k-means on bins, with no entry spanning more than 128 bins). Bins count with
weight sqrt(count), not count: the sparse tails (a few very large Gaussians, saturated colours)
then keep codebook entries of their own instead of being clipped into the dense middle. Every
value then takes its nearest entry.

`palette(points, size)` -> (centroids, labels): k-means with up to 65536 centroids on up to 45
dimensions, which flat Lloyd iterations cannot afford on a CPU (N x K x D per pass). It runs in
two levels: `coarse` k-means cells first (placed from a sample of 64 points a cell), then each
cell's points get their own k-means with a share of `size` proportional to the cell's count.
Cost per pass ~ N x (coarse + size/coarse) x D, about 1/256 of the flat version at 65536 centroids, with BLAS doing the
distances. Seeded: the same input gives the same palette.
"""

from __future__ import annotations

import numpy as np

__all__ = ["scalar_codebook", "nearest_scalar", "palette"]

HISTOGRAM_BINS = 1024
GROUP_BINS = 128  # longest codebook group searched (bins); 1024 bins / 256 entries average 4
COARSE_SAMPLE = 64  # points per coarse cell used to place the cells
_CHUNK = 1 << 15  # rows per distance block: bounds the (rows, centroids) temporary


def nearest_scalar(values: np.ndarray, codebook: np.ndarray) -> np.ndarray:
    """Index of the nearest entry of an ascending `codebook` for each value (uint8/uint16 safe)."""
    midpoints = (codebook[1:].astype(np.float64) + codebook[:-1]) * 0.5
    return np.searchsorted(midpoints, np.asarray(values, np.float64), side="right")


def scalar_codebook(values: np.ndarray, size: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """`size` float32 entries (ascending, padded by repeating the last) and each value's label."""
    flat = np.asarray(values, np.float64).ravel()
    if flat.size == 0:
        return np.zeros(size, np.float32), np.zeros(np.shape(values), np.intp)
    lo, hi = float(flat.min()), float(flat.max())
    if not hi - lo > 1e-20 * max(1.0, abs(lo)):
        return np.full(size, lo, np.float32), np.zeros(np.shape(values), np.intp)
    width = (hi - lo) / HISTOGRAM_BINS
    bins = np.minimum(((flat - lo) / width).astype(np.intp), HISTOGRAM_BINS - 1)
    counts = np.bincount(bins, minlength=HISTOGRAM_BINS).astype(np.float64)
    sums = np.bincount(bins, weights=flat, minlength=HISTOGRAM_BINS)
    used = counts > 0
    centres = sums[used] / counts[used]
    weights = np.sqrt(counts[used])
    entries = _optimal_1d(centres, weights, size)
    codebook = np.empty(size, np.float32)
    codebook[:len(entries)] = entries
    codebook[len(entries):] = codebook[len(entries) - 1]
    codebook.sort()
    return codebook, nearest_scalar(values, codebook).reshape(np.shape(values))


def _optimal_1d(x: np.ndarray, w: np.ndarray, k: int) -> np.ndarray:
    """Weighted 1D k-means on sorted `x`: the k contiguous groups with the least weighted SSE,
    among groups of at most GROUP_BINS bins (the first group excepted), found exactly."""
    n = len(x)
    if n <= k:
        return x.copy()
    pw = np.concatenate([[0.0], np.cumsum(w)])
    pwx = np.concatenate([[0.0], np.cumsum(w * x)])
    pwxx = np.concatenate([[0.0], np.cumsum(w * x * x)])

    def cost(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # group a..b inclusive
        sw = pw[b + 1] - pw[a]
        swx = pwx[b + 1] - pwx[a]
        with np.errstate(invalid="ignore", divide="ignore"):  # empty (invalid) groups: masked later
            return np.maximum((pwxx[b + 1] - pwxx[a]) - swx * swx / sw, 0.0)  # rounding: no negatives

    window = min(GROUP_BINS, n)
    d = np.arange(window)[:, None]  # a group ending at j starts at j - d
    j = np.arange(n)[None, :]
    valid = j - d >= 1  # room for the earlier groups before it
    start = np.where(valid, j - d, 1)
    band = np.where(valid, cost(start, np.broadcast_to(j, start.shape)), np.inf)
    best = cost(np.zeros(n, np.intp), np.arange(n))  # one group 0..j
    split = np.zeros((k, n), np.int32)  # split[m, j]: last bin of the earlier groups
    for m in range(1, k):
        previous = np.where(valid, best[np.maximum(start - 1, 0)], np.inf)
        candidates = previous + band
        arg = np.argmin(candidates, axis=0)
        best = candidates[arg, np.arange(n)]
        split[m] = np.arange(n) - arg - 1
    entries = np.empty(k)
    end = n - 1
    for m in range(k - 1, -1, -1):
        first = int(split[m, end]) + 1 if m > 0 else 0
        entries[m] = (pwx[end + 1] - pwx[first]) / (pw[end + 1] - pw[first])
        end = first - 1
    return entries


def _assign(points: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Nearest centroid per point (squared Euclidean), in blocks, with BLAS."""
    labels = np.empty(len(points), np.intp)
    half_norms = 0.5 * np.einsum("ij,ij->i", centroids, centroids)
    for lo in range(0, len(points), _CHUNK):
        block = points[lo:lo + _CHUNK]
        labels[lo:lo + len(block)] = np.argmin(half_norms - block @ centroids.T, axis=1)
    return labels


def _means(points: np.ndarray, labels: np.ndarray, k: int, previous: np.ndarray) -> np.ndarray:
    """Cluster means; a cluster that lost all its points keeps its previous centroid."""
    order = np.argsort(labels, kind="stable")
    present, starts, counts = np.unique(labels[order], return_index=True, return_counts=True)
    sums = np.add.reduceat(points[order], starts, axis=0, dtype=np.float64)
    out = previous.copy()
    out[present] = (sums / counts[:, None]).astype(points.dtype)
    return out


def _kmeans(points: np.ndarray, k: int, iterations: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if len(points) <= k:
        return points.copy(), np.arange(len(points))
    centroids = points[rng.choice(len(points), k, replace=False)].copy()
    labels = _assign(points, centroids)
    for _ in range(iterations):
        centroids = _means(points, labels, k, centroids)
        new = _assign(points, centroids)
        if np.array_equal(new, labels):
            break
        labels = new
    return centroids, labels


def _shares(counts: np.ndarray, total: int) -> np.ndarray:
    """Split `total` centroids over clusters in proportion to `counts` (largest remainder): at
    least one for each non-empty cluster, at most its count, summing to min(total, sum(counts))."""
    total = min(total, int(counts.sum()))
    ideal = counts * (total / counts.sum())
    share = np.clip(np.floor(ideal).astype(np.int64), np.minimum(counts, 1), counts)
    while share.sum() != total:
        give = share.sum() < total
        room = (share < counts) if give else (share > 1)
        gap = (ideal - share) if give else (share - ideal)
        candidates = np.flatnonzero(room)
        candidates = candidates[np.argsort(-gap[candidates], kind="stable")]
        need = abs(total - int(share.sum()))
        share[candidates[:need]] += 1 if give else -1
    return share


def palette(points: np.ndarray, size: int, *, coarse: int = 256, iterations: int = 6,
            seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Up to `size` float32 centroids for `points` (N, D) and each point's label (N,)."""
    points = np.ascontiguousarray(points, np.float32)
    rng = np.random.default_rng(seed)
    if len(points) <= size:
        return points.copy(), np.arange(len(points))
    coarse = min(coarse, size)
    # The coarse cells only split the work: learn them from a sample, then assign every point.
    sample = points[rng.choice(len(points), min(len(points), COARSE_SAMPLE * coarse), replace=False)]
    coarse_centroids, _ = _kmeans(sample, coarse, iterations, rng)
    coarse_labels = _assign(points, coarse_centroids)
    order = np.argsort(coarse_labels, kind="stable")
    counts = np.bincount(coarse_labels, minlength=coarse)
    shares = _shares(counts, size)
    centroids = np.empty((int(shares.sum()), points.shape[1]), np.float32)
    labels = np.empty(len(points), np.intp)
    start = first = 0
    for cluster in range(coarse):
        members = order[start:start + counts[cluster]]
        start += counts[cluster]
        if len(members) == 0:
            continue
        local_centroids, local_labels = _kmeans(points[members], int(shares[cluster]), iterations, rng)
        centroids[first:first + len(local_centroids)] = local_centroids
        labels[members] = first + local_labels
        first += len(local_centroids)
    return centroids[:first], labels
