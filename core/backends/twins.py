"""The twin table: every per-frame step that exists twice, in NumPy and compiled.

NumPy is the readable specification of each step and runs everywhere; the
compiled side (numba, :mod:`core.backends.numba`) does the same float operations
in the same order, in one parallel pass, and gives the same bits (or, where a
library ``exp``/``log`` differs, values within an ulp; the tests say which).

Each row of :data:`TWINS` names a step and the module that holds both of its
sides (its *home*). There the NumPy side is registered with :func:`numpy_side`,
which returns the function every caller uses, and the compiled side with
:func:`compiled_side`, with the condition under which it takes a call
(``supports``: the profile it covers, the dtypes it handles). Both sides take the
same arguments. A call runs the compiled side when the call's backend resolves to
numba (:func:`core.backends.select.compiled`) and ``supports`` holds, the NumPy
side otherwise: this module is the only place that dispatches.

The backend of a call is its ``backend`` argument, or ``params.backend`` for a
step that takes the parameters object instead.

The tests build their equivalence checks from this table
(``tests/core/backends/test_twins.py``): every row must have both sides bound
and cases to compare them on, so a new twin cannot go untested.
"""

from __future__ import annotations

import functools
import importlib
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any

from . import select


@dataclass
class Twin:
    """One step with a NumPy and a compiled implementation.

    Attributes
    ----------
    name : str, the step's name in the table
    home : str, the module (under ``core``) that holds and registers both sides
    what : str, one line on what the step computes
    numpy : callable or None, the NumPy side (set when ``home`` is imported)
    compiled : callable or None, the compiled side (idem)
    supports : callable or None, ``supports(*args, **kwargs) -> bool``: the compiled
        side takes this call (None: every call)
    """

    name: str
    home: str
    what: str
    numpy: Callable | None = None
    compiled: Callable | None = None
    supports: Callable[..., bool] | None = None


TWINS: dict[str, Twin] = {
    t.name: t
    for t in (
        Twin(
            "sampling",
            "mc.estimator",
            "the distant samples of every active SSS pixel, summed per pixel",
        ),
        Twin(
            "estimate_variance",
            "mc.estimator",
            "the variance of each pixel's estimate from its samples' sums",
        ),
        Twin("surface", "geometry", "area and normal of every pixel of the depth buffer"),
        Twin("float_image", "geometry", "per-pixel float values scattered into a float32 image"),
        Twin("row_mean", "geometry", "the mean of (P, 3) rows: the frame's lighting scale"),
        Twin(
            "burley_region",
            "profiles.burley",
            "γ, weight scale and sampling bounds of the Burley profile per pixel",
        ),
        Twin("spvg_counts", "mc.adaptive", "SPVG sample counts from the history (Alg. 1)"),
        Twin("spvg_update", "mc.adaptive", "SPVG history update (Eq. 5-7)"),
        Twin(
            "history_step",
            "mc.update",
            "tracked luminance, control variate and SPVG update, stored into the history",
        ),
        Twin("history_read", "mc.history", "history buffers read at pixels, in true units"),
        Twin("history_write", "mc.history", "values stored into history buffers at pixels"),
        Twin("reproject", "mc.history", "the history fetched along the motion vectors"),
        Twin(
            "neighbourhood",
            "mc.temporal",
            "mean and deviation over each pixel's 3×3 same-material neighbours",
        ),
        Twin("reuse_step", "mc.temporal", "the temporal reuse's per-pixel arithmetic"),
        Twin(
            "reuse",
            "mc.temporal",
            "the temporal reuse step: the history's reads, the arithmetic and the stores",
        ),
        Twin("separable_pass", "separable.apply", "one 1D pass of the separable filter"),
        Twin("composite", "result", "the finished frame and the lighting image"),
    )
}


def _backend_reader(fn: Callable) -> Callable[[tuple, dict], str]:
    """A function (args, kwargs) -> the call's backend, for the signature of ``fn``."""
    params = list(inspect.signature(fn).parameters.values())
    names = [p.name for p in params]
    for name, attribute in (("backend", None), ("params", "backend")):
        if name in names:
            position = names.index(name)
            default = params[position].default
            positional = params[position].kind in (
                inspect.Parameter.POSITIONAL_ONLY,
                inspect.Parameter.POSITIONAL_OR_KEYWORD,
            )

            def read(
                args, kwargs, name=name, position=position, default=default, attr=attribute,
                positional=positional,
            ):  # fmt: skip
                if name in kwargs:
                    value = kwargs[name]
                elif positional and len(args) > position:
                    value = args[position]
                else:
                    value = default
                return getattr(value, attr) if attr else value

            return read
    raise TypeError(f"{fn.__qualname__}: a twin takes a 'backend' or a 'params' argument")


def numpy_side(name: str) -> Callable[[Callable], Callable]:
    """Register the decorated function as the NumPy side of twin ``name``.

    Returns the function callers use: it runs the compiled side where the call's
    backend resolves to numba and the compiled side supports the call, the
    decorated NumPy function otherwise. The NumPy function stays reachable as
    ``.numpy`` (and the row as ``.twin``).
    """
    row = TWINS[name]

    def bind(fn: Callable) -> Callable:
        if row.numpy is not None:
            raise RuntimeError(f"twin {name!r} has a NumPy side already: {row.numpy.__qualname__}")
        row.numpy = fn
        backend_of = _backend_reader(fn)

        @functools.wraps(fn)
        def dispatch(*args: Any, **kwargs: Any) -> Any:
            backend = backend_of(args, kwargs)
            if (
                backend != "numpy"
                and row.compiled is not None
                and select.compiled(backend)
                and (row.supports is None or row.supports(*args, **kwargs))
            ):
                return row.compiled(*args, **kwargs)
            return row.numpy(*args, **kwargs)

        dispatch.numpy = fn
        dispatch.twin = row
        return dispatch

    return bind


def compiled_side(
    name: str, supports: Callable[..., bool] | None = None
) -> Callable[[Callable], Callable]:
    """Register the decorated function as the compiled side of twin ``name``.

    It takes the NumPy side's arguments, unpacks them into arrays and numbers and
    calls the passes of :func:`compiled_module`. ``supports(*args, **kwargs)`` says
    whether it takes a call (None: every call). Returns the function unchanged.
    """
    row = TWINS[name]

    def bind(fn: Callable) -> Callable:
        if row.compiled is not None:
            raise RuntimeError(f"twin {name!r} has a compiled side already")
        row.compiled = fn
        row.supports = supports
        return fn

    return bind


def compiled_module(domain: str) -> ModuleType:
    """The compiled passes of ``domain`` (a module of :mod:`core.backends.numba`),
    imported on first use: only a compiled side, which runs where numba imports,
    asks for it."""
    return importlib.import_module(f"{__package__}.numba.{domain}")
