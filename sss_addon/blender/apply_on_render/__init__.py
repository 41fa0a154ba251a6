"""Apply on Render: Blender's own F12, Ctrl-F12 and ``blender -b -f/-a`` deliver finished frames.

No Python compositor node runs per pixel, so with ``scene.sss_settings.apply_on_render``
the user's render itself becomes the pass render and an ordered worker
post-processes every frame Blender writes. Handlers (all ``@persistent``):

``render_init``
    What the user's render would make is read first (:mod:`.user_render`: the
    view layer's passes, the compositor; :func:`..render.job_from_scene`:
    Cycles' denoiser settings). The
    scene then switches to the pass configuration for the duration of the
    render (:class:`.user_render.KeepingPassSetup`: Subsurface Weight 0, pass
    indices and flags, compositor and sequencer off, 32-bit multilayer EXR
    into a temporary folder; the user's passes kept on when a compositor or a
    multilayer file takes them, the denoiser's guides stored when the scene
    denoises). Blender copies the render settings right after this handler,
    so its own render now renders passes. Before the switch a linked copy of
    the scene, emptied of everything but the camera, keeps the user's output
    settings and runs a copy of the user's compositor: the *output scene*. A
    problem the user can fix (another engine than Cycles or EEVEE, no camera,
    multi-view) stops the render with a message: the render engine becomes
    :class:`.engine.ResultEngine`, which reports the error, so Blender cancels
    before writing anything. When the post would change no pixel (no material
    takes part in subsurface, or Cycles renders every part: :mod:`..thin_parts`),
    no session starts and Blender renders the frame as without the add-on, with
    a note in the log and the panel.
``render_pre``
    The frame's sidecar (camera, materials) is taken. Output placeholders and
    *Overwrite* off are honoured here, as Blender does before it renders a
    frame.
``render_write``
    Blender has written the frame's pass EXR. On the first frame of a fresh
    history of an animation, with a method that reuses its history's
    estimates (:func:`.session.warm_up_pays`), ``warmup_frames`` frames
    before it are rendered (nested renders of a linked copy of the scene,
    which has its own Render) and processed, their output dropped: only here
    is it known whether the render is a still, which needs none. The worker
    reads the pass EXR, runs the
    method (:class:`core.run.FrameStream` owns the history; frames go in
    order, and consecutive renders such as ``-f 1..3`` continue it in
    background mode), denoises the finished frame as the scene's Cycles
    denoiser would (:mod:`..denoise_frame`), updates the SSS image datablocks
    and delivers the finished frame by rendering the output scene with
    :class:`.engine.ResultEngine`: its Render Layers nodes read the finished
    frame and the pass render's passes (:mod:`.frame_passes`,
    :mod:`.compositor`), Blender's own compositor runs, and Blender's own
    writer writes, so the path, frame number and extension rules, format,
    passes, colour management and dither are the user's.
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

What cannot be done as the user's render would is said before it starts
(:mod:`.notes`: the panel and the render's first lines).

Modules, one job each: :mod:`.user_render` (what the user's render makes,
and the pass configuration that keeps it), :mod:`.frame_passes` (the passes
a finished frame is delivered with), :mod:`.compositor` (the user's
compositor on the output scene), :mod:`.engine` (the render engine that
hands Blender a finished frame), :mod:`.scenes` (the scenes it renders with:
the output scene, the display setup), :mod:`.notes` (what differs from the
user's render), :mod:`.session` (one render of the user's: pass
configuration, temporary files, queue, warm-up, denoise, delivery) and
:mod:`.handlers` (Blender's render handlers and the UI's timer).
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
