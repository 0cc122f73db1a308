"""Intervals for a rate over several runs that were evaluated on the same problems (seeds of a recipe).

Pooling the runs' problems into one Wilson interval treats the same problem, rolled out by three seeds, as
three independent trials: its interval is about sqrt(3) too narrow when the seeds agree on a problem, which
they mostly do. The unit that was drawn at random is the problem, so the interval here resamples problems:
a percentile bootstrap over problems of the mean over runs, each resample drawing problems with replacement
and keeping every run's outcome on each (a cluster bootstrap, clusters being problems). Runs evaluated on
different problems are resampled each over its own problems. The interval is about the problems drawn,
for these runs: the spread between seeds is reported beside it (mean ± std), not inside it.

Where every outcome is the same (no successes at all, or all), a bootstrap has no spread; the Wilson
interval over the distinct problems stands in, which is what one run on those problems would report.
"""

from __future__ import annotations

import numpy as np

from samp.eval.metrics import wilson_interval

__all__ = ["RESAMPLES", "problem_bootstrap"]

RESAMPLES = 4000  # bootstrap resamples: the 2.5 % and 97.5 % quantiles move by < 0.3 points between seeds at n ~ 400
SEED = 0  # the resampling is seeded so that a table reads the same every time it is made


def problem_bootstrap(outcomes: list[dict[str, float]], level: float = 0.95, resamples: int = RESAMPLES,
                      seed: int = SEED) -> tuple[float, float] | None:
    """The percentile bootstrap interval, in [0, 1], of the mean over runs of a rate; `outcomes` holds per
    run {problem id: 0 or 1}. Runs on the same problems are resampled together (one draw of problems for
    all), others each on its own. None when a run has no problems."""
    if not outcomes or any(not o for o in outcomes):
        return None
    shared = set(outcomes[0]).intersection(*outcomes[1:])
    if all(len(o) == len(shared) for o in outcomes):
        ids = sorted(shared)
        blocks = [np.array([[o[i] for i in ids] for o in outcomes], dtype=float)]  # (runs, problems)
    else:
        blocks = [np.array([[o[i] for i in sorted(o)]], dtype=float) for o in outcomes]
    values = np.concatenate([b.ravel() for b in blocks])
    if values.min() == values.max():
        n = max(b.shape[1] for b in blocks)
        low, high = wilson_interval(int(round(values[0] * n)), n)
        return low, high
    rng = np.random.default_rng(seed)
    means = np.zeros(resamples)
    runs = sum(b.shape[0] for b in blocks)
    for b in blocks:
        draws = rng.integers(0, b.shape[1], size=(resamples, b.shape[1]))
        per_problem = b.sum(axis=0)  # the runs' outcomes on each problem, summed: one draw serves all runs
        means += per_problem[draws].mean(axis=1)  # the sum of the block's runs' rates on the resample
    means /= runs
    tail = (1 - level) / 2
    low, high = np.quantile(means, [tail, 1 - tail])
    return float(low), float(high)
