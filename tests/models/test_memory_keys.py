"""K-GEN: key properties (zero mean, unit energy, noise-like, shift-equivariant)."""

from __future__ import annotations

import numpy as np
import pytest

from models.memory_keys import KEY_METHODS, key_spectrum, make_key
from models.preprocess import normalise


def _pattern(seed: int, n: int = 64) -> np.ndarray:
    """A blurred random pattern, zero mean, unit energy (like a preprocessed image)."""
    rng = np.random.default_rng(seed)
    f = np.fft.rfft2(rng.standard_normal((n, n)))
    w2 = np.fft.fftfreq(n)[:, None] ** 2 + np.fft.rfftfreq(n)[None, :] ** 2
    return normalise(np.fft.irfft2(f * np.exp(-40.0 * w2), s=(n, n)))


def _ccorr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Circular cross-correlation c(d) = sum_x a(x) b(x + d)."""
    return np.fft.irfft2(np.conj(np.fft.rfft2(a)) * np.fft.rfft2(b), s=a.shape)


@pytest.mark.parametrize("method", KEY_METHODS)
@pytest.mark.parametrize("n", [16, 64, 65])
def test_zero_mean_unit_energy(method: str, n: int) -> None:
    k = make_key(_pattern(1, n), seed=3, method=method)
    assert k.shape == (n, n) and k.dtype == np.float32
    assert abs(float(k.mean())) < 1e-6
    assert float(np.sum(k.astype(np.float64) ** 2)) == pytest.approx(1.0, rel=1e-5)


@pytest.mark.parametrize("method", KEY_METHODS)
def test_autocorrelation_is_a_delta(method: str) -> None:
    k = make_key(_pattern(2), method=method).astype(np.float64)
    c = _ccorr(k, k)
    assert c[0, 0] == pytest.approx(1.0, rel=1e-5)
    assert np.abs(c.ravel()[1:]).max() < 1e-3


@pytest.mark.parametrize("method", KEY_METHODS)
def test_keys_of_different_patterns_are_uncorrelated(method: str) -> None:
    n = 64
    keys = [make_key(_pattern(s, n), method=method).astype(np.float64) for s in range(6)]
    for i in range(len(keys)):
        for j in range(i + 1, len(keys)):
            c = _ccorr(keys[i], keys[j])
            # noise-like: every lag about 1/n, nothing near the self peak of 1
            assert np.abs(c).max() < 6.0 / n
            assert np.std(c) == pytest.approx(1.0 / n, rel=0.1)


def test_key_is_noise_like_in_space() -> None:
    # the pattern is smooth (neighbour correlation high); its key is white (neighbour correlation ~0)
    p = _pattern(7)
    k = make_key(p).astype(np.float64)
    neighbour = lambda a: float(np.sum(a * np.roll(a, 1, axis=1)) / np.sum(a * a))  # noqa: E731
    assert neighbour(p) > 0.8
    assert abs(neighbour(k)) < 0.05


def test_similar_patterns_have_close_keys() -> None:
    p = _pattern(8).astype(np.float64)
    rng = np.random.default_rng(0)
    q = normalise(p + 0.3 * _pattern(9) + 0.002 * rng.standard_normal(p.shape))
    kp, kq = make_key(p).astype(np.float64), make_key(q).astype(np.float64)
    assert float(np.sum(kp * kq)) > 0.3  # far above the ~1/n of unrelated keys


def test_shift_moves_the_key_by_the_same_amount() -> None:
    p = _pattern(10)
    shifted = np.roll(p, (3, -2), axis=(0, 1))
    assert np.allclose(np.roll(make_key(p), (3, -2), axis=(0, 1)), make_key(shifted), atol=1e-5)
    c = _ccorr(make_key(p).astype(np.float64), make_key(shifted).astype(np.float64))
    assert np.unravel_index(np.argmax(c), c.shape) == (3, 62)


def test_seed_changes_key_not_crosscorrelation() -> None:
    p, q = _pattern(11), _pattern(12)
    assert abs(float(np.sum(make_key(p, seed=0) * make_key(p, seed=1)))) < 0.1
    c0 = _ccorr(make_key(p, seed=0).astype(np.float64), make_key(q, seed=0).astype(np.float64))
    c1 = _ccorr(make_key(p, seed=5).astype(np.float64), make_key(q, seed=5).astype(np.float64))
    assert np.allclose(c0, c1, atol=1e-6)


def test_a_linear_all_pass_key_would_not_be_noise_like() -> None:
    # why K-GEN is nonlinear: with FK = F(P) exp(i theta), K(P) (x) K(Q) = P (x) Q, a smooth
    # cross-correlation with a large peak, whereas the whitened keys stay at ~1/n
    n = 64
    p, q = _pattern(13, n).astype(np.float64), _pattern(14, n).astype(np.float64)
    theta = np.exp(1j * np.angle(np.fft.rfft2(np.random.default_rng(0).standard_normal((n, n)))))
    lin = lambda a: np.fft.irfft2(np.fft.rfft2(a) * theta, s=(n, n))  # noqa: E731
    assert np.allclose(_ccorr(lin(p), lin(q)), _ccorr(p, q), atol=1e-9)
    assert np.abs(_ccorr(p, q)).max() > 2.5 * np.abs(_ccorr(make_key(p), make_key(q))).max()


def test_zero_pattern_gives_zero_key() -> None:
    assert not make_key(np.zeros((8, 8))).any()
    assert not key_spectrum(np.zeros((8, 8))).any()


@pytest.mark.parametrize(
    ("args", "kwargs", "name"),
    [
        ((np.zeros((4, 5)),), {}, "pattern"),
        ((np.zeros(8),), {}, "pattern"),
        ((np.ones((8, 8)),), {"method": "linear"}, "method"),
        ((np.ones((8, 8)),), {"seed": -1}, "seed"),
    ],
)
def test_bad_arguments(args: tuple, kwargs: dict, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        make_key(*args, **kwargs)


@pytest.mark.parametrize("method", KEY_METHODS)
def test_a_patterns_phase_keys_every_seed_as_key_spectrum_does(method: str) -> None:
    """``seeded_key(key_phase(p))`` is ``key_spectrum(p)`` for every seed (the phase shared by the
    shards of a process, each adding its seed); an all-zero pattern has no phase, a zero key."""
    from models.memory_keys import key_phase, seeded_key

    rng = np.random.default_rng(41)
    for n in (8, 9, 32):
        p = rng.standard_normal((n, n))
        phase = key_phase(p, method=method)
        assert phase is not None and phase.shape == (n, n // 2 + 1)
        for seed in (0, 1, 7):
            np.testing.assert_array_equal(seeded_key(phase, seed=seed), key_spectrum(p, seed=seed, method=method))
    assert key_phase(np.zeros((8, 8)), method=method) is None
    with pytest.raises(ValueError, match="seed"):
        seeded_key(phase, seed=-1)
