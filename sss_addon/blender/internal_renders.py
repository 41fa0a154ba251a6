"""Which renders are the add-on's own (pass, ground-truth, denoise, warm-up, delivery).

Apply on Render's handlers run for every render Blender makes, the add-on's
own included; they leave alone the renders made inside :func:`internal_render`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

#: Depth of the add-on's own renders in progress (see :func:`internal_render`).
_internal = 0


@contextlib.contextmanager
def internal_render() -> Iterator[None]:
    """Mark the renders inside the block as the add-on's own.

    The Apply on Render handlers (apply_on_render/) leave these renders alone: the
    pass, ground-truth, denoise, warm-up and delivery renders are not the
    user's.
    """
    global _internal
    _internal += 1
    try:
        yield
    finally:
        _internal -= 1


def rendering_internally() -> bool:
    """Whether a render of the add-on's own is in progress (:func:`internal_render`)."""
    return _internal > 0
