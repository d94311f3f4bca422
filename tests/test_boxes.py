"""Box overlaps by sweep and prune (polyhull.engine.boxes) against brute force."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from polyhull.engine.boxes import any_overlap, overlap_groups


def _random_boxes(seed: int, n: int, spread: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lo = rng.uniform(0.0, spread, size=(n, 3))
    size = rng.exponential(0.15, size=(n, 3)) * rng.uniform(0.2, 3.0, size=(1, 3))  # anisotropic
    return lo, lo + size


def _meets(alo: np.ndarray, ahi: np.ndarray, blo: np.ndarray, bhi: np.ndarray) -> np.ndarray:
    return np.all((alo[:, None, :] <= bhi[None]) & (ahi[:, None, :] >= blo[None]), axis=2)


@settings(max_examples=40)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 120), spread=st.floats(0.1, 3.0))
def test_groups_are_the_connected_components_of_overlap(seed: int, n: int, spread: float) -> None:
    lo, hi = _random_boxes(seed, n, spread)
    labels = overlap_groups(lo, hi)
    _, expected = connected_components(csr_matrix(_meets(lo, hi, lo, hi)), directed=False)
    # the same partition: labels map one-to-one
    pairs = set(zip(labels.tolist(), expected.tolist(), strict=True))
    assert len(pairs) == len(set(labels.tolist())) == len(set(expected.tolist()))
    assert labels.min() == 0 and labels.max() == len(set(labels.tolist())) - 1


@settings(max_examples=40)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 80), m=st.integers(0, 80))
def test_any_overlap_is_brute_force(seed: int, n: int, m: int) -> None:
    qlo, qhi = _random_boxes(seed, n, 2.0)
    blo, bhi = _random_boxes(seed + 1, m, 2.0)
    expected = _meets(qlo, qhi, blo, bhi).any(axis=1) if m else np.zeros(n, dtype=bool)
    assert np.array_equal(any_overlap(qlo, qhi, blo, bhi), expected)
