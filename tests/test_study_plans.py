"""Study plans and sensitivities (jaxform.study.plans, spec, analysis): no JAX, no runs."""

import itertools
import math

import numpy as np
import pytest

from jaxform.errors import ConfigError
from jaxform.study import plans
from jaxform.study.analysis import correlations, main_effects, standardized_regression
from jaxform.study.spec import draw, parse_input, parse_response


@pytest.mark.parametrize("n, d, seed", [(16, 3, 0), (7, 5, 1), (64, 4, 12)])
def test_latin_hypercube_puts_one_sample_in_each_stratum(n, d, seed):
    """Reference: the definition of a Latin hypercube: per input, the n strata
    [k/n, (k+1)/n) hold exactly one sample each."""
    u = plans.latin_hypercube(n, d, seed)
    assert u.shape == (n, d) and np.all((u >= 0) & (u < 1))
    for j in range(d):
        assert sorted(np.floor(u[:, j] * n).astype(int)) == list(range(n))
    assert np.array_equal(u, plans.latin_hypercube(n, d, seed))  # the seed fixes it
    assert not np.array_equal(u, plans.latin_hypercube(n, d, seed + 1))


@pytest.mark.parametrize("m", [3, 5, 6])
def test_sobol_points_form_a_0_m_2_net(m):
    """Reference: the first two coordinates of a (scrambled) Sobol sequence form a
    (0, m, 2)-net in base 2 (Owen scrambling keeps the net property): every elementary box
    [a 2^-k, (a+1) 2^-k) x [b 2^-(m-k), (b+1) 2^-(m-k)) holds exactly one of the 2^m
    points; every 1-D stratum of width 2^-m holds one point in every coordinate."""
    n = 2**m
    u = plans.sobol(n, 4, seed=3)
    assert u.shape == (n, 4)
    for k in range(m + 1):
        boxes = np.floor(u[:, 0] * 2**k).astype(int) * 2 ** (m - k) + np.floor(
            u[:, 1] * 2 ** (m - k)
        ).astype(int)
        assert sorted(boxes) == list(range(n)), k
    for j in range(4):
        assert sorted(np.floor(u[:, j] * n).astype(int)) == list(range(n))


def test_sobol_refuses_a_sample_count_that_is_not_a_power_of_2():
    inp = parse_input("friction.m = uniform(0.1, 0.5)", "study.inputs[0]")
    with pytest.raises(ConfigError, match=r"study.samples = 10: a Sobol plan takes a power of 2"):
        draw([inp], "sobol", 10, 3, 0)


def test_full_factorial_counts_and_covers_every_combination():
    """Reference: a full factorial of levels counts 2 x 3 x 4 = 24 distinct rows, every
    combination once; a uniform input at study.levels = 4 gets equally spaced levels from
    low to high."""
    inputs = [
        parse_input("friction.m = levels(0.1, 0.3)", "a"),
        parse_input("die.speed_mm_s = levels(1, 2, 3)", "b"),
        parse_input("thermal.die_temperature_K = uniform(400, 700)", "c"),
    ]
    x = draw(inputs, "factorial", samples=1, levels=4, seed=0)
    assert x.shape == (24, 3)
    expected = set(itertools.product([0.1, 0.3], [1.0, 2.0, 3.0], [400.0, 500.0, 600.0, 700.0]))
    assert {tuple(r) for r in x} == expected


@pytest.mark.parametrize(
    "text, mean, std",
    [
        ("thermal.die_temperature_K = uniform(400, 700)", 550.0, 300.0 / math.sqrt(12.0)),
        ("thermal.die_temperature_K = normal(500, 20)", 500.0, 20.0),
        # lognormal(mu, sigma): mean exp(mu + sigma^2/2), variance (e^{s^2} - 1) mean^2
        (
            "die.speed_mm_s = lognormal(1.0, 0.25)",
            math.exp(1.0 + 0.25**2 / 2),
            math.exp(1.0 + 0.25**2 / 2) * math.sqrt(math.exp(0.25**2) - 1.0),
        ),
        # levels: each equally likely
        ("friction.m = levels(0.1, 0.2, 0.6)", 0.3, math.sqrt(np.var([0.1, 0.2, 0.6]))),
    ],
)
def test_monte_carlo_distributions_have_their_moments(text, mean, std):
    """Reference: the closed-form mean and standard deviation of each distribution;
    tolerance 5 standard errors of 40000 Monte-Carlo samples (seeded, so the test is
    deterministic): 5 std/sqrt(n) for the mean, 5 std sqrt(2/n) (normal theory, generous
    for the others) for the standard deviation."""
    n = 40_000
    x = draw([parse_input(text, "x")], "monte_carlo", n, 3, seed=11)[:, 0]
    assert abs(x.mean() - mean) < 5 * std / math.sqrt(n)
    assert abs(x.std() - std) < 5 * std * math.sqrt(2.0 / n) * 2


def test_latin_hypercube_of_a_normal_input_hits_the_quantiles():
    """Reference: the normal inverse CDF at each stratum: sample k of 200 lies between the
    k/200 and (k+1)/200 quantiles of normal(500, 20) (scipy.stats.norm.ppf)."""
    from scipy.stats import norm

    x = np.sort(draw([parse_input("thermal.die_temperature_K = normal(500, 20)", "x")],
                     "latin_hypercube", 200, 3, seed=2)[:, 0])  # fmt: skip
    q = norm.ppf(np.arange(201) / 200, 500, 20)
    assert np.all((x >= q[:-1]) & (x <= q[1:]))


@pytest.mark.parametrize(
    "text, needle",
    [
        ("die.nope = uniform(0, 1)", "unknown key die.nope"),
        ("friction.model = levels(1, 2)", "friction.model is not a numeric key"),
        ("friction.m = uniform(0.5, 1.5)", "1.5 is outside friction.m's allowed range [0, 1]"),
        ("friction.m = levels(-0.1, 0.2)", "-0.1 is outside friction.m's allowed range [0, 1]"),
        ("friction.m = uniform(0.5, 0.2)", "needs low < high"),
        ("friction.m = weibull(1, 2)", "'weibull' is not a distribution"),
        ("friction.m = normal(0.3)", "normal takes 2 numbers"),
        ("friction.m = normal(0.3, -1)", "must be > 0"),
        ("friction.m: 0.3", "expected 'section.key = uniform(low, high)'"),
    ],
)
def test_bad_inputs_name_the_key_and_what_is_allowed(text, needle):
    with pytest.raises(ConfigError) as err:
        parse_input(text, "study.inputs[0]")
    assert needle in str(err.value) and "study.inputs[0]" in str(err.value)
    assert "\n" not in str(err.value)


def test_responses_parse_and_name_their_columns():
    assert parse_response("force_N:max", "r").name == "force_N_max"
    assert parse_response("fill", "r").name == "die_fill_end"
    assert parse_response("flash", "r").name == "flash_volume_mm3_end"
    assert parse_response("laps", "r").name == "laps"
    with pytest.raises(ConfigError, match=r"study.responses\[0\] = 'force_N:mean'"):
        parse_response("force_N:mean", "study.responses[0]")


def test_standardized_regression_of_a_linear_response():
    """Reference: for y = sum_j c_j x_j exactly, SRC_j = c_j std(x_j) / std(y) (the fit is
    exact: r2 = 1), and the variance shares add up: src' R src = r2 with R the inputs'
    sample correlation matrix (to 1e-12); the correlation of an input the response
    ignores is small (below 0.1: the sampled inputs' own correlation)."""
    x = plans.latin_hypercube(400, 3, seed=4) * np.array([1.0, 10.0, 5.0])
    c = np.array([3.0, 0.05, 0.0])
    y = x @ c + 2.0
    src, r2 = standardized_regression(x, y)
    np.testing.assert_allclose(src, c * x.std(axis=0) / y.std(), rtol=1e-10, atol=1e-12)
    assert r2 == pytest.approx(1.0, abs=1e-12)
    assert src @ np.corrcoef(x.T) @ src == pytest.approx(r2, abs=1e-12)
    assert abs(correlations(x, y)[2]) < 0.1


def test_main_effects_average_the_response_per_level():
    """Reference: hand-computed means of y at each level of x."""
    x = np.array([1.0, 1.0, 2.0, 2.0, 3.0])
    y = np.array([1.0, 3.0, 10.0, 20.0, 7.0])
    levels, means = main_effects(x, y)
    np.testing.assert_array_equal(levels, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(means, [2.0, 15.0, 7.0])
