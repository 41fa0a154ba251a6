"""The one place that chooses the backend (core.backends.select): what runs, what the
log says, and the fallback to NumPy where numba does not import."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from cvsss.core.backends import select
from cvsss.core.params import ParameterError, SSSParams


def test_numba_runs_here():
    """The pinned environment has numba: the full lane measures the compiled passes, not a
    fallback (the NumPy-only lane, ``make test-numpy``, skips this)."""
    pytest.importorskip("numba")
    assert select.resolve("auto") == "numba"
    assert select.resolve("numpy") == "numpy"
    assert "numba" in select.describe("auto")
    assert select.threads() >= 1


def test_backend_parameter_is_validated():
    assert SSSParams().backend == "auto"
    with pytest.raises(ParameterError, match="backend must be one of auto, numpy, numba"):
        SSSParams(backend="cuda")
    with pytest.raises(ValueError, match="backend must be one of"):
        select.resolve("cuda")


def test_numpy_never_imports_numba():
    code = (
        "import sys; from cvsss.core.backends import select; "
        "print(select.compiled('numpy'), select.resolve('numpy'), 'numba' in sys.modules)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False", "numpy", "False"]


_NO_NUMBA = textwrap.dedent(
    """
    import json, logging, sys

    class Refuse:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("numba", "llvmlite"):
                raise ImportError(f"{name} is not installed")
            return None

    sys.meta_path.insert(0, Refuse())
    records = []
    handler = logging.Handler()
    handler.emit = lambda r: records.append((r.levelname, r.getMessage()))
    logging.getLogger("cvsss").addHandler(handler)
    logging.getLogger("cvsss").setLevel(logging.INFO)

    import numpy as np
    from cvsss.core.backends import select
    from cvsss.core.methods import make_processor
    from cvsss.core.params import SSSParams
    from cvsss.core.synthetic import scene_frame

    res = make_processor("as_ccv", SSSParams(backend="numba")).process(scene_frame("flash", 1, 64, 36))
    out = {
        "auto": select.resolve("auto"),
        "describe": select.describe("auto"),
        "numba_loaded": "numba" in sys.modules,
        "samples": int(res.samples),
        "finite": bool(np.isfinite(res.composite).all()),
        "log": records,
    }
    print(json.dumps(out))
    """
)


def test_clean_fallback_without_numba():
    """Where numba cannot be imported (no wheel for the platform) NumPy runs and the log says so."""
    env = {**os.environ, "PYTHONHASHSEED": "0"}
    proc = subprocess.run(
        [sys.executable, "-c", _NO_NUMBA], capture_output=True, text=True, env=env, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["auto"] == "numpy"
    assert out["numba_loaded"] is False
    assert out["samples"] > 0 and out["finite"]
    assert out["describe"].startswith("NumPy (numba unavailable (ImportError")
    # Asked for numba, got NumPy: a warning that says why; "auto" just informs.
    assert [
        lvl
        for lvl, msg in out["log"]
        if msg.startswith("cvsss: Monte Carlo backend numpy (asked numba")
    ] == ["WARNING"]
    assert any("NumPy fallback" in msg for _, msg in out["log"])
    assert any(
        lvl == "INFO" and msg.startswith("cvsss: Monte Carlo backend numpy (asked auto")
        for lvl, msg in out["log"]
    )
