"""The unscented λ rule ``filter.lam_rule``: Julier and Uhlmann's ``n + λ = 3`` against its analytic property, the
paper's ``λ = 0`` at ``n = 3``, and errors naming the key."""

import pytest
import torch

from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.filters.usque import UsqueParams
from lightcurve_gp.training.store import model_key

DT = torch.float64
ROBUST = "configs/boxwing_robust.yaml"


def axis_moments(params: UsqueParams, n: int) -> tuple[float, float]:
    """Second and fourth moment of the first state component under the sigma points of ``N(0, I_n)``."""
    lam, wm, _ = params.weights(n, dtype=DT)
    points = torch.cat([torch.zeros(1, n, dtype=DT), *(s * (n + lam) ** 0.5 * torch.eye(n, dtype=DT)
                                                        for s in (1.0, -1.0))])
    x = points[:, 0]
    return float((wm * x ** 2).sum()), float((wm * x ** 4).sum())


@pytest.mark.parametrize("n", [3, 4, 7, 10])
def test_julier_rule_matches_the_gaussian_fourth_moment_for_every_dimension(n):
    julier = UsqueParams(lam_rule="julier")
    assert julier.weights(n).lam == 3 - n
    second, fourth = axis_moments(julier, n)
    assert second == pytest.approx(1.0, abs=1e-14)
    assert fourth == pytest.approx(3.0, abs=1e-13)  # E[x⁴] of a standard normal


@pytest.mark.parametrize("n", [4, 7])
def test_lambda_zero_misses_the_fourth_moment_beyond_three_states(n):
    second, fourth = axis_moments(UsqueParams(lam=0.0), n)
    assert second == pytest.approx(1.0, abs=1e-14)
    assert fourth == pytest.approx(n, abs=1e-12)  # n + λ = n: the points sit √n out, too far for n > 3


def test_julier_rule_is_the_papers_lambda_at_three_states():
    given, julier = UsqueParams(lam=0.0).weights(3, dtype=DT), UsqueParams(lam_rule="julier").weights(3, dtype=DT)
    assert given.lam == julier.lam == 0.0
    assert torch.equal(given.wm, julier.wm) and torch.equal(given.wc, julier.wc)


def test_config_key_reaches_the_filter_and_leaves_the_model_key():
    base = load_config(ROBUST, overrides=["filter.lam_rule=given"])
    julier = load_config(ROBUST, overrides=["filter.lam_rule=julier"])
    assert UsqueParams.from_config(julier).weights(7).lam == -4.0
    assert UsqueParams.from_config(base).weights(7).lam == base.filter.lam
    assert model_key(base) == model_key(julier)


def test_bad_rule_names_its_key():
    with pytest.raises(ConfigError, match="^filter.lam_rule"):
        load_config(ROBUST, overrides=["filter.lam_rule=scaled"])
    with pytest.raises(ValueError, match="^lam_rule must be one of given, julier, got 'scaled'$"):
        UsqueParams(lam_rule="scaled")
