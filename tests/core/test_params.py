import math

import pytest

from cvsss.core.params import PAPER_DEFAULTS, ParameterError, SSSParams


def test_defaults_are_the_papers():
    p = SSSParams()
    for name, value in PAPER_DEFAULTS.items():
        assert getattr(p, name) == value
    # A cold history samples at β_max (not the paper's β_min): measured against Cycles.
    assert p.initial_count == p.beta_max
    assert SSSParams(n_init=12).initial_count == 12


@pytest.mark.parametrize(
    ("name", "value", "fragment"),
    [
        ("eta", 0.0, "eta must be in (0, 1]"),
        ("eta", 1.5, "eta must be in (0, 1]"),
        ("target_variance", 0.0, "target_variance must be in (0, inf)"),
        ("target_variance", -1e-4, "target_variance"),
        ("eps_u", 1.1, "eps_u must be in [0, 1]"),
        ("eps_alpha", -1.0, "eps_alpha"),
        ("kappa", 2.0, "kappa must be in [0, 1]"),
        ("beta_min", 0, "beta_min must be in [1, 4096]"),
        ("beta_max", 5000, "beta_max must be in [1, 4096]"),
        ("eta_cv", 0.0, "eta_cv"),
        ("seed", -1, "seed"),
        ("history_precision", "float64", "history_precision must be one of"),
        ("burley_inverse", "approx", "burley_inverse"),
        ("eta", math.nan, "eta must be finite"),
        ("beta_min", 2.5, "beta_min must be an integer"),
        ("eta", "0.2", "eta must be a number"),
    ],
)
def test_invalid_values_name_the_argument(name, value, fragment):
    with pytest.raises(
        ParameterError,
        match=fragment.replace("(", r"\(")
        .replace(")", r"\)")
        .replace("[", r"\[")
        .replace("]", r"\]"),
    ):
        SSSParams(**{name: value})


def test_beta_order_checked():
    with pytest.raises(ParameterError, match="beta_min must be <= beta_max"):
        SSSParams(beta_min=32, beta_max=16)


@pytest.mark.parametrize(
    "changes",
    [
        {"eta": 1e-6},
        {"eta": 1.0},
        {"eta_cv": 1e-9},
        {"eta_cv": 1.0},
        {"target_variance": 1e-12},
        {"target_variance": 1e6},
        {"kappa": 0.0},
        {"kappa": 1.0},
        {"eps_u": 0.0},
        {"eps_u": 1.0},
        {"eps_alpha": 0.0},
        {"eps_alpha": 1.0},
        {"beta_min": 16, "beta_max": 16},
        {"beta_min": 1, "beta_max": 1},
        {"beta_max": 1024},
    ],
)
def test_extremes_are_accepted(changes):
    p = SSSParams(**changes)
    assert p.replace() == p
    assert set(p.to_dict()) == set(SSSParams.field_names())
