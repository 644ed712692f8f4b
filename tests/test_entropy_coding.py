"""Entropy coding of integer vectors under quantised priors (brdfcodec.layers.entropy_coding)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfcodec.layers.entropy_coding import decode_integers, encode_integers, ideal_code_length_bits


def _vectors(seed: int, count: int) -> list[tuple[np.ndarray, np.ndarray, int]]:
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(count):
        n = int(rng.integers(1, 200))
        spreads = np.exp(rng.normal(0, 2, n))
        bound = int(rng.choice([1, 7, 255, 4095]))
        q = np.clip(np.rint(rng.laplace(0, spreads / math.sqrt(2))), -bound, bound).astype(np.int64)
        cases.append((q, spreads, bound))
    return cases


@pytest.mark.parametrize("prior", ["laplace", "gaussian"])
def test_round_trip_is_exact(prior: str) -> None:
    for q, spreads, bound in _vectors(0, 60):
        data = encode_integers(q, spreads, bound=bound, prior=prior)  # type: ignore[arg-type]
        assert decode_integers(data, spreads, bound=bound, prior=prior).tolist() == q.tolist()  # type: ignore[arg-type]


def test_symbols_at_the_bound_and_far_in_the_tail_round_trip() -> None:
    spreads = np.array([0.01, 0.01, 1000.0, 0.5])
    q = np.array([255, -255, 0, -3])
    data = encode_integers(q, spreads, bound=255)
    assert decode_integers(data, spreads, bound=255).tolist() == q.tolist()


def test_the_same_input_gives_the_same_bytes() -> None:
    q, spreads, bound = _vectors(1, 1)[0]
    assert encode_integers(q, spreads, bound=bound) == encode_integers(q.copy(), spreads.copy(), bound=bound)


def test_length_is_within_about_a_byte_of_the_ideal() -> None:
    excess = []
    for q, spreads, bound in _vectors(2, 80):
        data = encode_integers(q, spreads, bound=bound)
        excess.append(len(data) - ideal_code_length_bits(q, spreads, bound=bound) / 8)
    assert max(excess) < 1.5
    assert np.mean(excess) < 0.8


def test_the_termination_is_the_shortest_that_decodes() -> None:
    for q, spreads, bound in _vectors(3, 30):
        data = encode_integers(q, spreads, bound=bound)
        if not data:
            continue
        shorter = data[:-1]
        candidates = [shorter]
        if shorter:
            value = int.from_bytes(shorter, "big") + 1
            if value < 256 ** len(shorter):
                candidates.append(value.to_bytes(len(shorter), "big"))
        for candidate in candidates:
            try:
                decoded = decode_integers(candidate, spreads, bound=bound).tolist()
            except ValueError:  # FileFormatError is a ValueError
                continue
            assert decoded != q.tolist()


def test_likely_vectors_cost_few_bits() -> None:
    spreads = np.full(300, 0.05)  # nearly always 0: about 300·0.0004 bits
    data = encode_integers(np.zeros(300, dtype=int), spreads, bound=1023)
    assert len(data) <= 2
    assert decode_integers(data, spreads, bound=1023).tolist() == [0] * 300


def test_an_empty_vector_is_empty_bytes() -> None:
    assert encode_integers([], np.zeros(0), bound=1) == b""
    assert decode_integers(b"", np.zeros(0), bound=1).shape == (0,)


@pytest.mark.parametrize("kwargs", [
    {"symbols": [5], "spreads": [1.0], "bound": 4},
    {"symbols": [0.5], "spreads": [1.0], "bound": 4},
    {"symbols": [0, 0], "spreads": [1.0], "bound": 4},
    {"symbols": [0], "spreads": [0.0], "bound": 4},
    {"symbols": [0], "spreads": [np.nan], "bound": 4},
    {"symbols": [0], "spreads": [1.0], "bound": 0},
    {"symbols": [0], "spreads": [1.0], "bound": 4, "prior": "cauchy"},
])
def test_bad_input_is_refused(kwargs: dict) -> None:  # type: ignore[type-arg]
    symbols = kwargs.pop("symbols")
    with pytest.raises(ValueError):
        encode_integers(symbols, **kwargs)
    with pytest.raises(ValueError):
        ideal_code_length_bits(symbols, **kwargs)


def test_per_entry_bounds_round_trip_and_cost_less_than_one_wide_bound() -> None:
    rng = np.random.default_rng(4)
    spreads = np.exp(rng.normal(0, 2, 150))
    bounds = np.clip(np.ceil(16 * spreads), 1, 2**16).astype(int)
    q = np.clip(np.rint(rng.laplace(0, spreads / math.sqrt(2))), -bounds, bounds).astype(int)
    data = encode_integers(q, spreads, bound=bounds)
    assert decode_integers(data, spreads, bound=bounds).tolist() == q.tolist()
    assert len(data) <= len(encode_integers(q, spreads, bound=2**16))
    with pytest.raises(ValueError):
        encode_integers(q, spreads, bound=bounds[:-1])
    wrong = q.copy()
    wrong[0] = bounds[0] + 1
    with pytest.raises(ValueError):
        encode_integers(wrong, spreads, bound=bounds)
