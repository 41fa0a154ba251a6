"""Every twin of the table (core.backends.twins) is bound on both sides, dispatched by
the table, and tested: the NumPy side against the compiled side on every case of
twin_cases.py, generated from the table itself, so a new twin cannot go untested."""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from twin_cases import CASES

from cvsss.core.backends import twins
from cvsss.core.backends.twins import TWINS

numba = pytest.importorskip("numba")


def _homes() -> None:
    for row in TWINS.values():
        importlib.import_module(f"cvsss.core.{row.home}")


def test_every_twin_is_bound_on_both_sides_in_its_home():
    _homes()
    for name, row in TWINS.items():
        assert row.numpy is not None, f"{name}: no NumPy side registered"
        assert row.compiled is not None, f"{name}: no compiled side registered"
        for side in (row.numpy, row.compiled):
            assert side.__module__ == f"cvsss.core.{row.home}", (name, side.__module__)


def test_every_twin_has_equivalence_cases():
    assert set(CASES) == set(TWINS)
    for name, make in CASES.items():
        assert make(), f"{name}: no cases"


_ALL = [(name, case) for name, make in CASES.items() for case in make()]


@pytest.mark.parametrize(("name", "case"), _ALL, ids=[f"{n}-{c.id}" for n, c in _ALL])
def test_numpy_and_compiled_sides_agree(name, case):
    """The NumPy side (backend "numpy") and the compiled side (backend "numba") on the
    same inputs, each on its own copy; the compiled side takes the case itself."""
    _homes()
    row = TWINS[name]
    args_a, kwargs_a = case.build("numpy")
    args_b, kwargs_b = case.build("numba")
    if row.supports is not None:
        assert row.supports(*args_b, **kwargs_b), f"{name}: the compiled side refuses the case"
    with np.errstate(all="ignore"):
        a = row.numpy(*args_a, **kwargs_a)
        b = row.compiled(*args_b, **kwargs_b)
    case.check(a, b, (args_a, kwargs_a), (args_b, kwargs_b))


@pytest.mark.parametrize("name", list(TWINS))
def test_the_table_dispatches_on_the_backend(name, monkeypatch):
    """A call with backend "numba" runs the compiled side, one with "numpy" the NumPy
    side, through the function callers use (the table's dispatcher)."""
    _homes()
    row = TWINS[name]
    case = CASES[name]()[0]
    calls = []
    compiled, numpy_side = row.compiled, row.numpy
    monkeypatch.setattr(row, "compiled", lambda *a, **k: calls.append("numba") or compiled(*a, **k))
    monkeypatch.setattr(row, "numpy", lambda *a, **k: calls.append("numpy") or numpy_side(*a, **k))
    dispatcher = _dispatcher(row)
    for backend in ("numba", "numpy"):
        args, kwargs = case.build(backend)
        with np.errstate(all="ignore"):
            dispatcher(*args, **kwargs)
    assert calls[0] == "numba" and calls[-1] == "numpy", calls


def _dispatcher(row: twins.Twin):
    """The function callers use for ``row`` (the one :func:`twins.numpy_side` returned)."""
    module = importlib.import_module(f"cvsss.core.{row.home}")
    for value in vars(module).values():
        candidates = [value, *vars(value).values()] if isinstance(value, type) else [value]
        for fn in candidates:
            if getattr(fn, "twin", None) is row:
                return fn
    raise AssertionError(f"{row.name}: no dispatcher in cvsss.core.{row.home}")


def test_the_compiled_side_is_skipped_where_it_does_not_apply():
    """``supports`` sends calls the compiled side does not cover to NumPy: a float16
    history, a Burley subclass, float32 ``shaded``, integer maps."""
    from cvsss.core.mc.history import History
    from cvsss.core.profiles.burley import BurleyProfile

    index = np.arange(10, dtype=np.int64)
    half = History.empty((4, 5), "float16", 1e-3, 1e-4)
    assert not TWINS["history_read"].supports(half, ("mu",), index)
    assert TWINS["history_read"].supports(History.empty((4, 5)), ("mu",), index)
    assert not TWINS["history_read"].supports(
        History.empty((4, 5)), ("mu",), index.astype(np.int32)
    )

    class Other(BurleyProfile):
        pass

    d = np.array([[0, 0, 0], [0.01, 0.01, 0.01]])
    assert TWINS["burley_region"].supports(BurleyProfile(d), None, None)
    assert not TWINS["burley_region"].supports(Other(d), None, None)
    assert not TWINS["composite"].supports(None, None, np.zeros((1, 3), np.float32))
    assert not TWINS["float_image"].supports((2, 2), index[:2], np.array([1, 2]))


def test_a_twin_cannot_be_registered_twice():
    row = TWINS["composite"]
    with pytest.raises(RuntimeError, match="NumPy side already"):
        twins.numpy_side("composite")(lambda frame, backend="numpy": None)
    with pytest.raises(RuntimeError, match="compiled side already"):
        twins.compiled_side("composite")(lambda frame, backend="numpy": None)
    assert row.numpy is not None


def test_a_twin_needs_a_backend_argument():
    with pytest.raises(TypeError, match="'backend' or a 'params'"):
        twins._backend_reader(lambda x: x)
