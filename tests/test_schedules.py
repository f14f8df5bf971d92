"""PriorFit's lr schedules and the correction's own lr (pdeinv.util.schedules, PriorFit(lr=None))."""

from __future__ import annotations

import math

import pytest

from pdeinv.nets.corrections import DenseCorrection, GridCorrection
from pdeinv.nets.refine import PriorFit
from pdeinv.util.schedules import Constant, Cosine


def test_cosine_runs_from_one_to_its_floor_through_the_half_cosine():
    s = Cosine(floor=0.1)
    assert s(0, 100) == pytest.approx(1.0) and s(100, 100) == pytest.approx(0.1)
    assert s(50, 100) == pytest.approx(0.1 + 0.9 * 0.5)
    assert s(25, 100) == pytest.approx(0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi / 4)))
    assert s(200, 100) == pytest.approx(0.1)  # past the end: the floor
    assert Constant()(7, 10) == 1.0


@pytest.mark.parametrize("floor", [-0.1, 1.5, float("nan"), True, "0"])
def test_a_cosine_floor_outside_zero_one_is_refused(floor):
    with pytest.raises(ValueError, match=r"Cosine\(floor="):
        Cosine(floor=floor)


def test_the_default_fit_is_constant_at_the_corrections_own_lr():
    fit = PriorFit()
    assert isinstance(fit.schedule, Constant) and fit.lr is None
    assert GridCorrection.fit_lr == 4e-3 and DenseCorrection.fit_lr == 1e-3


@pytest.mark.parametrize("lr", [0, -1e-3, float("inf"), float("nan"), True, "1e-3"])
def test_a_prior_fit_lr_that_is_not_a_finite_positive_number_is_refused(lr):
    with pytest.raises(ValueError, match=r"PriorFit\(lr="):
        PriorFit(lr=lr)


def test_a_schedule_that_is_not_callable_is_refused():
    with pytest.raises(TypeError, match=r"PriorFit\(schedule="):
        PriorFit(schedule="cosine")
