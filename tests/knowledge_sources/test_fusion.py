"""The fusion rule of ranking sources, on synthetic rankings."""

from __future__ import annotations

import numpy as np
import pytest

from knowledge_sources.fusion import (
    ABSOLUTE_SOURCES,
    ABSOLUTE_TRUST,
    evidence,
    fuse_rankings,
    fuse_shards,
    fused_log_posterior,
    shards_log_posterior,
    standardise,
    trust,
)


def _source(rng, n, truth, *, separation, noise=1.0, scale=1.0, offset=0.0):
    """Errors of n viewframes, the truth ``separation`` noise-sigmas better than the others."""
    e = rng.normal(0.0, noise, n)
    e[truth] -= separation * noise
    return list(range(n)), list(offset + scale * e)


def test_standardise_is_robust_and_scale_free():
    e = np.array([1.0, 2.0, 3.0, 4.0, 100.0])
    z = standardise(e)
    assert z[2] == 0.0 and z[4] > 20  # the median is 0; an outlier does not inflate the spread
    np.testing.assert_allclose(standardise(1e-6 * e + 5.0), z, rtol=1e-6)
    assert np.all(np.isfinite(standardise([2.0, 2.0, 2.0])))  # no spread: zeros, not infinities


def test_a_single_source_passes_through_unchanged():
    labels, errors = [3, 1, 2], [0.5, 0.1, 0.5]
    assert fuse_rankings({"associative": (labels, errors)}) == [(1, 0.1), (2, 0.5), (3, 0.5)]


def test_fusion_does_not_depend_on_a_robust_sources_units():
    rng = np.random.default_rng(0)
    a = _source(rng, 40, 7, separation=2.0)
    b = _source(rng, 40, 7, separation=2.0)
    base = fuse_rankings({"associative": a, "other": b})
    rescaled = fuse_rankings(
        {"associative": (a[0], [1e-5 * v + 3.0 for v in a[1]]), "other": (b[0], [40.0 * v for v in b[1]])}
    )
    assert "associative" not in ABSOLUTE_SOURCES and "other" not in ABSOLUTE_SOURCES
    assert [k for k, _ in base] == [k for k, _ in rescaled]


def test_an_absolute_sources_scale_is_its_reliability():
    """The skyline's errors are degrees: a failed horizon (every viewframe off by about the
    truncation, a little noise) must not outvote a confident associative ranking, as the per-frame
    standardisation of the first rule let it; a clean fit of one viewframe must decide."""
    rng = np.random.default_rng(5)
    n, truth = 32, 9
    assoc = _source(rng, n, truth, separation=5.0)
    failed = list(range(n)), list(1.8 + 0.05 * rng.normal(size=n))
    failed[1][20] = 1.65  # its best is wrong, but by a hair in degrees
    w = {"associative": 0.64, "skyline": 3.8}
    assert fuse_rankings({"associative": assoc, "skyline": failed}, weights=w)[0][0] == truth
    # the first rule (both standardised) follows the failed skyline's noise instead
    assert fuse_rankings({"associative": assoc, "skyline": failed}, weights={"skyline": 4.0}, absolute=())[0][0] == 20
    clean = list(range(n)), [0.3 if k == 14 else 1.2 + 0.1 * rng.normal() for k in range(n)]
    weak = _source(rng, n, 15, separation=1.0)  # a neighbour, weakly
    assert fuse_rankings({"associative": weak, "skyline": clean}, weights=w)[0][0] == 14
    np.testing.assert_allclose(evidence([2.0, 1.5, 3.0], absolute=True), [0.5, 0.0, 1.5])


@pytest.mark.parametrize(("best", "expected"), [(0.2, 1.0), (0.5, 1.0), (0.75, 0.5), (1.0, 0.0), (1.6, 0.0)])
def test_trust_falls_with_the_best_error(best, expected):
    lo, hi = ABSOLUTE_TRUST["skyline"]
    assert (lo, hi) == (0.5, 1.0)
    assert trust([best + 0.4, best, best + 1.0], (lo, hi)) == pytest.approx(expected)
    assert trust([best], None) == 1.0 and trust([], (lo, hi)) == 1.0
    with pytest.raises(ValueError, match="lo < hi"):
        trust([best], (1.0, 1.0))


def test_a_skyline_that_fits_nothing_well_is_not_trusted():
    """A horizon found wrongly fits some wrong viewframe least badly (0.85 degrees) and the others
    worse: its differences are noise. Untrusted, the memory decides; a clean skyline (its best
    fit 0.3 degrees) is fused as before, at full weight."""
    rng = np.random.default_rng(11)
    n, truth = 32, 9
    assoc = _source(rng, n, truth, separation=2.0)
    wrong = list(range(n)), [0.85 if k == 20 else 1.4 + 0.1 * rng.normal() for k in range(n)]
    w = {"associative": 0.64, "skyline": 3.8}
    assert fuse_rankings({"associative": assoc, "skyline": wrong}, weights=w, trusts={})[0][0] == 20
    assert fuse_rankings({"associative": assoc, "skyline": wrong}, weights=w)[0][0] == truth
    worse = wrong[0], [e + 0.2 for e in wrong[1]]  # its best fit 1.05 degrees: no trust at all
    lab, log_p = fused_log_posterior({"associative": assoc, "skyline": worse}, weights=w)
    lab_m, log_p_m = fused_log_posterior({"associative": assoc}, weights=w)
    np.testing.assert_allclose(log_p, log_p_m)  # not trusted at all: the memory's posterior alone
    clean = list(range(n)), [0.3 if k == 14 else 1.2 + 0.1 * rng.normal() for k in range(n)]
    assert fuse_rankings({"associative": assoc, "skyline": clean}, weights=w) == fuse_rankings(
        {"associative": assoc, "skyline": clean}, weights=w, trusts={}
    )


def test_the_fused_log_posterior_is_normalised_and_orders_as_the_ranking():
    rng = np.random.default_rng(6)
    a = _source(rng, 25, 3, separation=2.5)
    b = list(range(25)), list(np.abs(rng.normal(1.0, 0.3, 25)))
    w = {"associative": 0.64, "skyline": 3.8}
    labels, logp = fused_log_posterior({"associative": a, "skyline": b}, weights=w)
    assert list(labels) == list(range(25)) and np.exp(logp).sum() == pytest.approx(1.0)
    ranked = fuse_rankings({"associative": a, "skyline": b}, weights=w)
    assert [k for k, _ in ranked][:5] == list(labels[np.argsort(-logp, kind="stable")][:5])
    # F is the negative log likelihood ratio against the best, in nats
    best = int(np.argmax(logp))
    for k, f in ranked[:5]:
        assert f == pytest.approx(logp[best] - logp[k])


def test_two_weak_independent_sources_beat_either_alone():
    """Each source alone puts the truth first in few frames; fused, in many more."""
    rng = np.random.default_rng(1)
    hits = {"associative": 0, "skyline": 0, "fused": 0}
    trials, n = 300, 30
    for _ in range(trials):
        truth = int(rng.integers(n))
        a = _source(rng, n, truth, separation=2.0, scale=1e-4)  # variances
        b = _source(rng, n, truth, separation=2.0, scale=0.7, offset=1.0)  # degrees
        hits["associative"] += fuse_rankings({"associative": a})[0][0] == truth
        hits["skyline"] += fuse_rankings({"skyline": b})[0][0] == truth
        hits["fused"] += fuse_rankings({"associative": a, "skyline": b})[0][0] == truth
    assert hits["fused"] > 1.3 * max(hits["associative"], hits["skyline"]), hits


def test_weights_follow_the_better_source_and_zero_ignores_one():
    rng = np.random.default_rng(2)
    n, truth = 20, 4
    good = _source(rng, n, truth, separation=6.0)
    bad = _source(rng, n, 11, separation=6.0)  # confidently wrong
    assert fuse_rankings({"a": good, "b": bad}, weights={"a": 3.0, "b": 1.0})[0][0] == truth
    assert fuse_rankings({"a": good, "b": bad}, weights={"a": 1.0, "b": 3.0})[0][0] == 11
    only = fuse_rankings({"a": good, "b": bad}, weights={"a": 1.0, "b": 0.0})
    assert only == fuse_rankings({"a": good})


def test_a_viewframe_a_source_did_not_rank_counts_as_its_worst():
    a = ([0, 1, 2, 3], [0.1, 0.2, 0.3, 0.4])
    b = ([0, 1, 2], [0.3, 0.2, 0.1])  # has no opinion on 3
    fused = dict(fuse_rankings({"a": a, "b": b}))
    assert set(fused) == {0, 1, 2, 3}
    assert fused[3] == max(fused.values())


@pytest.mark.parametrize("weights, match", [({"a": -1.0}, "must be >= 0"), ({"a": 0.0}, "positive weight")])
def test_bad_weights_are_refused(weights, match):
    with pytest.raises(ValueError, match=match):
        fuse_rankings({"a": ([0, 1], [0.1, 0.2])}, weights=weights)


def test_fuse_shards_merges_each_source_then_fuses():
    from models.associative import Ranking

    rng = np.random.default_rng(7)
    a, b = rng.random(12), rng.random(12) * 5.0
    labels = np.arange(12)
    shards = {
        "associative": [Ranking(labels[:7], a[:7], 0.0), Ranking(labels[7:], a[7:], 0.0)],
        "skyline": [Ranking(labels[::-1], b[::-1], 0.0)],
    }
    weights = {"associative": 0.64, "skyline": 3.8}
    assert fuse_shards(shards, weights=weights) == fuse_rankings(
        {"associative": (labels, a), "skyline": (labels, b)}, weights=weights
    )
    # one source: its shards merged, its own errors best first (the identity of the fusion)
    only = fuse_shards({"associative": shards["associative"]})
    assert [k for k, _ in only] == list(np.argsort(a)) and [e for _, e in only] == sorted(a.tolist())
    # the tracker's view of the same shards: the normalised log posterior, in the fused ranking's order
    lab, log_p = shards_log_posterior(shards, weights=weights)
    assert np.exp(log_p).sum() == pytest.approx(1.0)
    fused = fuse_shards(shards, weights=weights)
    np.testing.assert_allclose(-log_p[np.array([k for k, _ in fused])] + log_p.max(), [f for _, f in fused], atol=1e-9)


def _fused_by_hand(rankings, weights):
    """The fusion written out per viewframe (a dict over the union of the ranked viewframes)."""
    from knowledge_sources.fusion import ABSOLUTE_SOURCES, evidence

    universe = sorted({int(k) for labels, _ in rankings.values() for k in labels})
    total = dict.fromkeys(universe, 0.0)
    for s, (labels, errors) in rankings.items():
        u = evidence(errors, absolute=s in ABSOLUTE_SOURCES)
        mine = dict(zip((int(k) for k in labels), u.tolist()))
        for k in universe:
            total[k] += weights[s] * mine.get(k, float(u.max()))
    low = min(total.values())
    return {k: v - low for k, v in total.items()}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fusion_of_a_window_and_a_full_ranking_is_the_per_viewframe_rule(seed):
    """Sources that ranked different viewframes (a track window beside a full ranking, shards in
    any order): the fused scores are those of the rule written out per viewframe."""
    from knowledge_sources.fusion import fuse_rankings, fused_log_posterior

    rng = np.random.default_rng(seed)
    n = 300
    full = rng.permutation(n)
    window = rng.permutation(np.arange(120, 170))
    rankings = {
        "associative": (window.tolist(), rng.gamma(2.0, 1.0, window.size).tolist()),
        "skyline": (full.tolist(), rng.uniform(0.2, 2.0, n).tolist()),
    }
    weights = {"associative": 0.64, "skyline": 3.8}
    want = _fused_by_hand(rankings, weights)
    got = fuse_rankings(rankings, weights=weights)
    assert [k for k, _ in got] == sorted(want, key=lambda k: (want[k], k))
    assert np.allclose([v for _, v in got], [want[k] for k, _ in got], rtol=0, atol=1e-12)
    labels, log_p = fused_log_posterior(rankings, weights=weights)
    assert labels.tolist() == sorted(want)
    assert np.argmax(log_p) == labels.tolist().index(got[0][0])
