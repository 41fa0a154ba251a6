"""Blender's render handlers that drive Apply on Render, and the UI's timer.

Every handler is ``@persistent`` (it stays across file loads) and leaves the
add-on's own renders alone (``internal_renders.rendering_internally``). What
each does is told in the package's doc; the work is the
:class:`.session.Session`'s. :func:`register` adds the handlers and, in the UI,
the timer (:func:`_poll`) that starts ``sss.finish_render`` once Blender's
render job has ended.
"""

from __future__ import annotations

import contextlib
import threading

import bpy
from bpy.app.handlers import persistent

from .. import materials as sss_materials
from .. import thin_parts
from ..errors import RenderError
from ..internal_renders import rendering_internally
from .engine import ENGINE, refuse
from .notes import NOTHING_TO_DO
from .session import Session, active_session, forget_history, log, start_session

#: (scene, engine) of a render stopped at render_init, put back at its end.
_stopped: tuple[object, str] | None = None


def _wanted(scene) -> bool:
    if rendering_internally():
        return False
    settings = getattr(scene, "sss_settings", None)
    return settings is not None and settings.apply_on_render


def _stop(scene, message: str) -> None:
    """Make Blender cancel this render before it writes anything, with ``message``."""
    global _stopped
    log("error: " + message)
    _stopped = (scene, scene.render.engine)
    refuse("cvsss: " + message)
    scene.render.engine = ENGINE


def _ours(scene) -> Session | None:
    session = active_session()
    if session is None or session.closed or session.rendered or rendering_internally():
        return None
    return session if session.scene == scene else None


def _on_render_thread() -> bool:
    """Whether the handler runs on Blender's render thread (a UI render), not the main one."""
    return threading.current_thread() is not threading.main_thread()


@persistent
def on_render_init(scene, *_args) -> None:
    if not _wanted(scene):
        return
    deferred = _on_render_thread()
    previous = active_session()
    if previous is not None and not previous.deferred:
        # Blender gave up on that render before it began (its render_init failed after
        # ours): nothing will end it, so it ends here.
        previous.cancelled = previous.rendered = True
        previous.close()
    if active_session() is not None:
        _stop(scene, "the previous render is still being finished; render again when it is done")
        return
    engine = scene.render.engine
    # Nothing for the post to change: Blender renders the frame as without the add-on
    # (a box left ticked must not stop the renders of scenes without subsurface).
    materials = sss_materials.participating(scene)
    if not materials:
        log(NOTHING_TO_DO)
        return
    if thin_parts.cycles_renders(scene.sss_settings.thin_walks, engine):
        whole = thin_parts.thin_objects(scene)
        if thin_parts.cycles_renders_all(scene, engine, materials=materials, thin=whole):
            walks, burleys = thin_parts.kinds(whole)
            log(thin_parts.all_thin_note(True, bool(walks), bool(burleys)))
            return
    try:
        start_session(scene, deferred)
    except RenderError as exc:
        _stop(scene, str(exc))
    except Exception as exc:  # the user's render must not run half-configured
        _stop(scene, f"could not prepare the render: {type(exc).__name__}: {exc}")


@persistent
def on_render_pre(scene, *_args) -> None:
    session = _ours(scene)
    if session is None or session.error is not None:
        return
    frame = int(scene.frame_current)
    try:
        session.frame_started(frame)
    except Exception as exc:  # reported, and the render stopped
        session.abort(f"frame {frame}: {type(exc).__name__}: {exc}")
    if session.filter is not None:
        session.filter.forward()


@persistent
def on_render_write(scene, *_args) -> None:
    session = _ours(scene)
    if session is None or session.error is not None:
        return
    frame = int(scene.frame_current)
    try:
        session.frame_written(frame)
        if not session.deferred and not session.still:
            # Here, not at render_pre: only now is it known whether this is a still.
            if session.stream is None and session.open_stream(session.pending[0][0]):
                for _ in session.warm_up_steps(session.pending[0][0]):
                    pass
            while session.pending:
                text = session.process_next()
                if session.movie:
                    text += " (movie: encoded after the last frame)"
                else:
                    text += " " + session.deliver_next()
                log(text)
    except Exception as exc:  # reported, and the render stopped
        session.abort(f"frame {frame}: {type(exc).__name__}: {exc}")


@persistent
def on_render_stats(*_args) -> None:
    session = active_session()
    if session is not None and session.filter is not None and not session.rendered:
        session.filter.forward()


def _ended(scene, cancelled: bool) -> None:
    global _stopped
    if _stopped is not None and _stopped[0] == scene and not rendering_internally():
        stopped_scene, engine = _stopped
        _stopped = None
        refuse(None)
        stopped_scene.render.engine = engine
        return
    session = _ours(scene)
    if session is None:
        return
    session.rendered = True
    session.cancelled = cancelled
    if session.deferred:
        return  # the main thread finishes (_poll)
    with contextlib.suppress(Exception):  # restored, and the error logged, by finish_steps
        for _ in session.finish_steps():
            pass


@persistent
def on_render_complete(scene, *_args) -> None:
    _ended(scene, cancelled=False)


@persistent
def on_render_cancel(scene, *_args) -> None:
    _ended(scene, cancelled=True)


@persistent
def on_save_pre(*_args) -> None:
    """A save while a render is being finished (UI): the user's scene goes to the file."""
    session = active_session()
    if session is not None:
        session.suspend()


@persistent
def on_save_post(*_args) -> None:
    session = active_session()
    if session is not None:
        session.resume()


@persistent
def on_load_pre(*_args) -> None:
    """A file is loaded over a session that never finished: put the scene back first."""
    session = active_session()
    if session is not None:
        session.close()


def _poll() -> float:
    """UI: start finishing a render once Blender's render job is over."""
    session = active_session()
    if (
        session is not None
        and session.deferred
        and not session.closed
        and not session.finishing
        and not bpy.app.is_job_running("RENDER")
    ):
        if not session.rendered:  # the job ended without render_complete/cancel
            session.cancelled = session.rendered = True
        session.finishing = True
        wm = bpy.context.window_manager
        window = wm.windows[0] if wm and wm.windows else None
        try:
            if window is None:
                for _ in session.finish_steps():
                    pass
            else:
                with bpy.context.temp_override(window=window):
                    bpy.ops.sss.finish_render("INVOKE_DEFAULT")
        except Exception as exc:  # never leave the scene switched
            log(f"error: {type(exc).__name__}: {exc}")
            session.close()
    return 0.25


_HANDLERS = {
    "render_init": on_render_init,
    "render_pre": on_render_pre,
    "render_write": on_render_write,
    "render_stats": on_render_stats,
    "render_complete": on_render_complete,
    "render_cancel": on_render_cancel,
    "load_pre": on_load_pre,
    "save_pre": on_save_pre,
    "save_post": on_save_post,
    # Blender 4.3+: a save that failed (the file unwritable) also ends the suspension.
    "save_post_fail": on_save_post,
}


def register() -> None:
    for name, handler in _HANDLERS.items():
        if hasattr(bpy.app.handlers, name):
            getattr(bpy.app.handlers, name).append(handler)
    if not bpy.app.background:
        bpy.app.timers.register(_poll, first_interval=1.0, persistent=True)


def unregister() -> None:
    if bpy.app.timers.is_registered(_poll):
        bpy.app.timers.unregister(_poll)
    for name, handler in _HANDLERS.items():
        handlers = getattr(bpy.app.handlers, name, ())
        if handler in handlers:
            handlers.remove(handler)
    session = active_session()
    if session is not None:
        session.close()
    forget_history()
