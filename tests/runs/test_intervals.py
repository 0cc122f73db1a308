"""The interval of a rate over seeds evaluated on the same problems (`samp.runs.intervals`), against the
normal approximation of the mean over problems, computed here, and against the Wilson interval."""

from __future__ import annotations

import math
from statistics import NormalDist

import numpy as np

from samp.runs.intervals import problem_bootstrap

Z = NormalDist().inv_cdf(0.975)


def _outcomes(matrix: np.ndarray) -> list[dict[str, float]]:
    return [{f"p{i}": float(v) for i, v in enumerate(row)} for row in matrix]


def _normal(matrix: np.ndarray) -> tuple[float, float]:
    """mean ± z SE, the SE that of the per-problem mean over runs (problems are the independent draws)."""
    per_problem = matrix.mean(axis=0)
    se = per_problem.std(ddof=1) / math.sqrt(per_problem.size)
    return per_problem.mean() - Z * se, per_problem.mean() + Z * se


def test_correlated_seeds_match_the_normal_approximation():
    rng = np.random.default_rng(7)
    hard = rng.random(400) < 0.3  # problems most seeds fail
    matrix = np.array([np.where(hard, rng.random(400) < 0.25, rng.random(400) < 0.95) for _ in range(3)])
    low, high = problem_bootstrap(_outcomes(matrix))
    want = _normal(matrix)
    assert abs(low - want[0]) < 0.01 and abs(high - want[1]) < 0.01, ((low, high), want)


def test_agreeing_seeds_count_each_problem_once():
    outcome = np.r_[np.ones(320), np.zeros(80)]
    low, high = problem_bootstrap(_outcomes(np.tile(outcome, (3, 1))))
    p, n = 0.8, 400
    width = 2 * Z * math.sqrt(p * (1 - p) / n)  # one run's width; 1200 pooled rollouts would give width / sqrt(3)
    assert abs((high - low) - width) < 0.1 * width, (high - low, width)


def test_runs_on_different_problems_are_resampled_apart():
    rng = np.random.default_rng(3)
    a, b = rng.random(300) < 0.9, rng.random(300) < 0.6
    got = problem_bootstrap([{f"a{i}": float(v) for i, v in enumerate(a)}, {f"b{i}": float(v) for i, v in enumerate(b)}])
    # the mean of two independent rates: variance (p1 q1 / n + p2 q2 / n) / 4
    p1, p2 = a.mean(), b.mean()
    se = math.sqrt(p1 * (1 - p1) / 300 + p2 * (1 - p2) / 300) / 2
    mid = (p1 + p2) / 2
    assert abs(got[0] - (mid - Z * se)) < 0.01 and abs(got[1] - (mid + Z * se)) < 0.01, (got, mid, se)


def test_no_spread_falls_back_to_wilson_over_the_problems():
    low, high = problem_bootstrap(_outcomes(np.ones((3, 50))))
    assert high == 1.0 and abs(low - 50 / (50 + Z * Z)) < 1e-9  # Wilson's lower bound at 50 of 50
    assert problem_bootstrap([{}, {"p0": 1.0}]) is None
