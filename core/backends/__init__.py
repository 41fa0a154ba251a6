"""The backends floor: which implementation of a per-frame step runs, NumPy or numba.

Nothing here imports from above it: the floors below are the parameters
(:mod:`core.params`), the frame data (:mod:`core.frame`, :mod:`core.camera`),
colour (:mod:`core.color`) and the sampling sequence (:mod:`core.sampling`).

:mod:`.select`
    The one place that chooses: ``SSSParams.backend`` ("auto", "numpy" or
    "numba") resolved against whether numba imports here.
:mod:`.twins`
    The twin table: every step that has a compiled implementation beside its
    NumPy one, and the dispatch between them. The tests generate their
    equivalence checks from it.
:mod:`.numba`
    The compiled passes, one module per domain, taking arrays and numbers only.
:mod:`.cache`, :mod:`.compile`
    Where numba keeps the compiled code on disk, and compiling all of it.
"""
