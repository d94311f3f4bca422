"""The removals the dynamic rules report (polyhull.engine.dynamic_rules._removed): each
removed component's rule, volume and volume centroid, and the pieces the shell rule cut
from a kept component, against a direct sum over each component's pieces."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from polyhull.engine.dynamic_rules import _removed


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 300), K=st.integers(1, 12))
def test_removed_volumes_and_centroids_are_the_pieces_sums(seed: int, n: int, K: int) -> None:
    rng = np.random.default_rng(seed)
    _, labels = np.unique(rng.integers(0, K, n), return_inverse=True)  # every component has a piece
    K = int(labels.max()) + 1
    lo = rng.uniform(0.0, 5.0, (n, 3))
    hi = lo + rng.uniform(0.01, 0.3, (n, 3))
    volumes = np.prod(hi - lo, axis=1)
    shell_cut = rng.random(n) < 0.3
    removed_c = rng.random(K) < 0.4
    rule_of = np.where(removed_c, "too_small", "").astype(object)
    component_volume = np.bincount(labels, weights=volumes, minlength=K)
    vertices = np.zeros((n, 8, 3))
    got = _removed(labels, K, lo, hi, volumes, shell_cut, removed_c, rule_of, component_volume, lambda idx: idx, vertices)

    expected = []
    for k in range(K):  # the shell rule's cuts of kept components first, then whole removals
        idx = np.nonzero((labels == k) & shell_cut)[0]
        if len(idx) and not removed_c[k]:
            expected.append(("too_thin", idx))
    expected += [("too_small", np.nonzero(labels == k)[0]) for k in range(K) if removed_c[k]]
    assert [r.rule for r in got] == [rule for rule, _ in expected]
    for r, (_, idx) in zip(got, expected, strict=True):
        vol = volumes[idx].sum()
        centre = (0.5 * (lo[idx] + hi[idx]) * volumes[idx, None]).sum(axis=0) / vol
        assert r.volume == np.float64(vol) or abs(r.volume - vol) <= 1e-12 * max(vol, 1.0)
        np.testing.assert_allclose(r.centroid, centre, rtol=1e-12, atol=1e-12)
        assert np.array_equal(np.sort(r._mesh._idx), idx)  # the pieces drawn are the component's


def test_no_removal_reports_nothing() -> None:
    n = 5
    labels = np.arange(n)
    lo = np.zeros((n, 3))
    hi = np.ones((n, 3))
    got = _removed(
        labels, n, lo, hi, np.ones(n), np.zeros(n, bool), np.zeros(n, bool), np.full(n, "", dtype=object),
        np.ones(n), lambda idx: idx, np.zeros((n, 8, 3)),
    )
    assert got == ()
