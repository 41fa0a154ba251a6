"""Shared by the check scripts beside it: a steady ``as_ccv`` frame of the bench's flash scene.

Not a check itself; the scripts import it by name (Python puts a script's own
folder first on ``sys.path``).
"""

from cvsss.core.frame import Frame
from cvsss.core.methods import MethodOptions, make_processor
from cvsss.core.params import SSSParams
from cvsss.core.result import FrameResult
from cvsss.core.synthetic import scene_frame


def steady(
    size: tuple[int, int], params: SSSParams, options: MethodOptions | None = None
) -> tuple[Frame, object, FrameResult]:
    """Frame 3 of the flash sequence (``core.synthetic``) at ``size`` (W, H pixels) after
    frames 1–2 through ``as_ccv``: the frame, its profile and its result (whose sample
    counts are a steady frame's)."""
    w, h = size
    frames = [scene_frame("flash", n, w, h) for n in (1, 2, 3)]
    proc = make_processor("as_ccv", params, options or MethodOptions())
    for frame in frames:
        result = proc.process(frame)
    return frames[-1], proc.profiles.get(frames[-1]), result
