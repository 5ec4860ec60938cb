"""Which photos to match with which: the pairs, chosen by the capture.

- `exhaustive`: every pair; certain, and quadratic: for small sets.
- `sequential`: each photo with the next `overlap` ones (and, with `quadratic`, with those 2, 4,
  8, ... ahead, as COLMAP's quadratic overlap does): for a video, in frame order. Quadratic
  overlap is off: on beer's video (a symmetric can) its long-range pairs matched the can's back
  to its front and placed 20 frames on the wrong side (docs/benchmarks/reconstruction.md).
- `retrieval`: each photo with the `neighbours` photos that look most alike, found with visual
  words computed from this capture's own SIFT descriptors (k-means on a sample, then tf-idf
  histograms compared by cosine; Sivic and Zisserman's "Video Google"), plus the sequential
  pairs of a short overlap: sub-quadratic in matching for a few hundred unordered photos, with
  nothing downloaded (COLMAP's vocabulary trees are files fetched from the internet).

`choose` picks one: a video is sequential; up to `EXHAUSTIVE_MAX` photos are exhaustive; more
photos use retrieval. Photos are not matched sequentially by default: their names need not be
their capture order (cup's 77 photos placed 39 that way, against 77 exhaustively). Names are in
natural order everywhere.
"""

from __future__ import annotations

import numpy as np

METHODS = ("auto", "exhaustive", "sequential", "retrieval")
EXHAUSTIVE_MAX = 100  # 4,950 pairs, about 40 s on 2 cores at 800x600 (docs/benchmarks)
SEQUENTIAL_OVERLAP = 10
RETRIEVAL_NEIGHBOURS = 20
RETRIEVAL_OVERLAP = 3
VOCABULARY_SIZE = 512
SAMPLE_PER_IMAGE = 512  # descriptors per photo for the vocabulary and the histograms


def choose(method: str, kind: str, count: int) -> str:
    """The method `auto` stands for (else `method` itself)."""
    if method != "auto":
        return method
    if kind == "video":
        return "sequential"
    return "exhaustive" if count <= EXHAUSTIVE_MAX else "retrieval"


def exhaustive(count: int) -> list[tuple[int, int]]:
    return [(i, j) for i in range(count) for j in range(i + 1, count)]


def sequential(count: int, overlap: int = SEQUENTIAL_OVERLAP,
               quadratic: bool = False) -> list[tuple[int, int]]:
    pairs = set()
    for i in range(count):
        steps = set(range(1, overlap + 1))
        if quadratic:
            steps |= {2 ** k for k in range(overlap)}
        pairs |= {(i, i + s) for s in steps if i + s < count}
    return sorted(pairs)


def _kmeans(samples: np.ndarray, k: int, rng: np.random.Generator,
            iterations: int = 8) -> np.ndarray:
    centres = samples[rng.choice(len(samples), size=k, replace=False)].copy()
    for _ in range(iterations):
        labels = nearest(samples, centres)
        sums = np.zeros_like(centres)
        np.add.at(sums, labels, samples)
        counts = np.bincount(labels, minlength=k)
        filled = counts > 0
        centres[filled] = sums[filled] / counts[filled, None]
    return centres


def nearest(points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Index of the nearest centre (Euclidean) for each point."""
    distance = (centres * centres).sum(1)[None, :] - 2.0 * points @ centres.T
    return np.argmin(distance, axis=1)


def similarity(descriptors: list[np.ndarray], *, words: int = VOCABULARY_SIZE,
               seed: int = 0) -> np.ndarray:
    """(N, N) cosine similarity of the photos' tf-idf visual-word histograms (diagonal 0)."""
    rng = np.random.default_rng(seed)
    sampled = []
    for d in descriptors:
        d = np.asarray(d, np.float32)
        if len(d) > SAMPLE_PER_IMAGE:
            d = d[rng.choice(len(d), size=SAMPLE_PER_IMAGE, replace=False)]
        sampled.append(d)
    pool = np.concatenate([d for d in sampled if len(d)]) if any(len(d) for d in sampled) \
        else np.zeros((0, 128), np.float32)
    n = len(descriptors)
    if len(pool) < words:
        return np.zeros((n, n))
    centres = _kmeans(pool, words, rng)
    histograms = np.zeros((n, words))
    for i, d in enumerate(sampled):
        if len(d):
            histograms[i] = np.bincount(nearest(d, centres), minlength=words)
    document_frequency = (histograms > 0).sum(0)
    idf = np.log(n / np.maximum(document_frequency, 1))
    weighted = histograms / np.maximum(histograms.sum(1, keepdims=True), 1) * idf
    weighted /= np.maximum(np.linalg.norm(weighted, axis=1, keepdims=True), 1e-12)
    result = weighted @ weighted.T
    np.fill_diagonal(result, 0.0)
    return result


def retrieval(similar: np.ndarray, neighbours: int = RETRIEVAL_NEIGHBOURS,
              overlap: int = RETRIEVAL_OVERLAP) -> list[tuple[int, int]]:
    """Each photo with its `neighbours` most similar, and its `overlap` next in order."""
    n = len(similar)
    pairs = set(sequential(n, overlap, quadratic=False))
    k = min(neighbours, n - 1)
    if k > 0:
        best = np.argsort(-similar, axis=1)[:, :k]
        pairs |= {(min(i, int(j)), max(i, int(j))) for i in range(n) for j in best[i] if i != j}
    return sorted(pairs)
