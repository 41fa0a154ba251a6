"""The one sequence driver: frame in → results, metric rows, checkpoint.

``cvsss post``, ``cvsss render``, ``cvsss demo`` and the Blender operators all
drive a :class:`core.run.driver.SequenceRun`: they hand it frames in order (read from pass
EXRs, rendered on the way, or made in memory) and it runs every method of the
run on each, writes the results, the metric rows and a checkpoint per method,
and resumes from those checkpoints.

Layout written under ``out``::

    out/<method>/0001.exr           result layers (core.io.exr.write_result)
    out/<method>/.checkpoint.npz    history + metric rows after the last finished frame,
                                    with each finished frame's pass files (size, mtime)
    out/metrics.csv                 one row per frame and method (core.eval.rows)

History is carried from frame to frame per method, so frames are processed in
order. The metric rows are those of :mod:`core.eval.rows`. The reference (for
``psnr_db``) keeps no history, so computing it on every k-th frame only
(``reference_every``) is exact.

Modules: :mod:`.spec` (what a run computes), :mod:`.driver` (the driver),
:mod:`.resume` (checkpoints), :mod:`.folder` (a folder of pass EXRs).

Existing results
----------------
``existing`` says what happens to results already in ``out``:

``"error"``
    Refuse (the default of ``cvsss post``): nothing is replaced unasked.
``"resume"``
    Continue each method after its checkpoint; bit-identical to an
    uninterrupted run (timings aside). Refused when the checkpoint belongs
    to another run (other passes, methods or parameters), when a pass file
    of a frame it covers changed since (size or modification time, see
    ``inputs`` of :class:`core.run.driver.SequenceRun`), when it is damaged, and when
    ``metrics.csv`` holds rows of a method that is not resumed from its
    checkpoint (rewriting it would drop them).
``"overwrite"``
    Start over, replacing results, checkpoints and metrics.
``"continue"``
    Resume where the checkpoint belongs to the same run, start over
    otherwise (``cvsss render``, ``cvsss demo`` and the Blender operators:
    their results are derived from the pass files they keep).

Every file is written atomically (core.io.atomic), so a run killed at any
instant leaves complete files only; temporaries of dead runs are removed.

Writing in the background
-------------------------
Given ``submit`` (``cvsss post`` passes a one-thread executor's: the core
starts no threads itself), a frame's files — its results, then the
checkpoints, then ``metrics.csv``, in the order an inline run writes them —
are handed over as one job and written while the next frame is read:
encoding a result EXR takes about as long as the frame's subsurface
scattering at 1920×1080, and reading and checking the next frame's passes
leaves a core free. :meth:`core.run.driver.SequenceRun.step` waits for the previous frame's
files before any method runs, so the writing never slows the timed steps
(``sampling_ms``, ``frame_ms``), and raises their error (OutputError) there;
:meth:`core.run.driver.SequenceRun.finish` and :meth:`~core.run.driver.SequenceRun.wait` wait for the last. A
checkpoint is still written only after its frame's result, so a resumed run
never skips a frame whose file is missing. The files are the same as an
inline run's (timing figures aside).
"""

from .driver import FrameStream, Progress, SequenceRun, Step
from .folder import check_sequence, run_folder
from .resume import CHECKPOINT_NAME, file_stamps
from .spec import EXISTING, RunSpec

__all__ = [
    "CHECKPOINT_NAME",
    "EXISTING",
    "FrameStream",
    "Progress",
    "RunSpec",
    "SequenceRun",
    "Step",
    "check_sequence",
    "file_stamps",
    "run_folder",
]
