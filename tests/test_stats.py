"""Student's t intervals (Table 3's intervals over games), against published table values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lwm_models.stats import mean_interval, t_quantile, t_two_sided


@pytest.mark.parametrize(
    ("df", "t975"),
    [(1, 12.706), (2, 4.303), (3, 3.182), (4, 2.776), (9, 2.262), (10, 2.228), (29, 2.045), (120, 1.980)],
)
def test_quantiles_match_the_t_table(df, t975):
    assert t_quantile(0.95, df) == pytest.approx(t975, abs=6e-4)
    assert t_two_sided(t975, df) == pytest.approx(0.95, abs=2e-4)


def test_many_degrees_of_freedom_approach_the_normal():
    assert t_quantile(0.95, 2000) == pytest.approx(1.96, abs=2e-3)
    assert t_quantile(0.99, 5) == pytest.approx(4.032, abs=1e-3)


def test_the_interval_of_ten_games_is_the_t_interval():
    returns = np.array([1.5, -1.0, 0.5, 1.5, 1.5, -0.75, 0.25, 1.5, -1.0, 1.0])
    mean, lo, hi = mean_interval(returns)
    half = 2.2622 * returns.std(ddof=1) / math.sqrt(10)
    assert mean == pytest.approx(returns.mean()) and hi - mean == pytest.approx(half, rel=1e-4)
    assert (hi - mean) / (1.96 * returns.std(ddof=1) / math.sqrt(10)) == pytest.approx(1.154, abs=1e-3)
    assert mean_interval([0.5]) == (0.5, 0.5, 0.5)
    with pytest.raises(ValueError):
        mean_interval([])
