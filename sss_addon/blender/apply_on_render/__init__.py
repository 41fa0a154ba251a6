"""Apply on Render: Blender's own F12, Ctrl-F12 and ``blender -b -f/-a`` deliver finished frames.

No Python compositor node runs per pixel, so with ``scene.sss_settings.apply_on_render``
the user's render itself becomes the pass render and an ordered worker
post-processes every frame Blender writes. Handlers (all ``@persistent``):

``render_init``
    The scene switches to the pass configuration for the duration of the
    render (:class:`.passes.PassSetup`: Subsurface Weight 0, pass indices and
    flags, compositor and sequencer off, 32-bit multilayer EXR into a
    temporary folder). Blender copies the render settings right after this
    handler, so its own render now renders passes. Before the switch a
    linked copy of the scene, emptied of everything but the camera, keeps the
    user's output settings: the *output scene*. A problem the user can fix
    (another engine than Cycles or EEVEE, no camera, no subsurface material,
    multi-view) stops the render with a message: the render engine becomes
    :class:`.engine.ResultEngine`, which reports the error, so Blender cancels before
    writing anything.
``render_pre``
    The frame's sidecar (camera, materials) is taken. On the first frame of
    a fresh history ``warmup_frames`` frames before it are rendered (nested
    renders of a linked copy of the scene, which has its own Render) and
    processed, their output dropped. Output placeholders and *Overwrite* off
    are honoured here, as Blender does before it renders a frame.
``render_write``
    Blender has written the frame's pass EXR. The worker reads it, runs the
    method (:class:`core.run.FrameStream` owns the history; frames go in
    order, and consecutive renders such as ``-f 1..3`` continue it in
    background mode), updates the SSS image datablocks and delivers the
    finished frame by rendering the output scene with :class:`.engine.ResultEngine`:
    Blender's own writer, so the path, frame number and extension rules,
    format, colour management and dither are the user's.
``render_complete`` / ``render_cancel``
    A still render (F12) is rendered once more on the user's scene with
    :class:`.engine.ResultEngine`, so the Render Result is the finished frame and a
    ``write_still`` render writes it where Blender would; a movie (FFmpeg)
    is encoded from the finished frames by one animation render of the
    output scene (Blender's own movie writer); then every setting is
    restored and the temporary files removed — also after an error or Esc.

In background mode (``blender -b``, the ``bpy`` module) the handlers run on
the main thread and all of this happens inside them, frame by frame. With
the UI, Blender calls them on its render thread: there ``render_init`` only
switches the settings and the frames are queued; when the render job has
ended, a timer starts the modal ``sss.finish_render`` operator, which warms
up, processes and delivers one frame per tick on the main thread (progress
in the status bar, Esc stops and restores).

Blender's ``Saved: '…'`` lines about the temporary pass files (and the
output of the nested renders) leave stdout in background mode; one line per
frame reports what was delivered where.

Modules, one job each: :mod:`.engine` (the render engine that hands Blender a
finished frame), :mod:`.scenes` (the scenes it renders with: the output
scene, the display setup, the checks of the user's scene), :mod:`.session`
(one render of the user's: pass configuration, temporary files, queue,
warm-up, delivery) and :mod:`.handlers` (Blender's render handlers and the
UI's timer).
"""

from . import engine, handlers

#: Registration order: the engine before the handlers that switch scenes to it.
_MODULES = (engine, handlers)


def register() -> None:
    for module in _MODULES:
        module.register()


def unregister() -> None:
    for module in reversed(_MODULES):
        module.unregister()
