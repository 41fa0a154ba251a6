"""Apply on Render: Blender's own render delivers the finished frames (real Cycles, tiny frames).

The reference of every comparison is ``cvsss render`` (standalone.render_sequence)
on the same scene, frames and settings: its linear Composite, written with
the scene's colour management (Image.save_render) for 8-bit formats.
"""

import gc
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.io.exr import read_result  # noqa: E402
from cvsss.sss_addon import precompile  # noqa: E402
from cvsss.sss_addon.blender import apply_on_render, standalone  # noqa: E402
from cvsss.sss_addon.blender.apply_on_render import handlers  # noqa: E402
from cvsss.sss_addon.blender.apply_on_render.engine import ResultEngine  # noqa: E402
from cvsss.sss_addon.blender.apply_on_render.session import Session, active_session  # noqa: E402

pytestmark = pytest.mark.bpy

ROOT = Path(__file__).resolve().parents[2]
FRAMES = (1, 3)


@pytest.fixture
def scene(demo, tmp_path):
    """The flash demo at 48x27, 4 samples, frames 1–3, Apply on Render on, no warm-up."""
    demo.render.resolution_x, demo.render.resolution_y = 48, 27
    demo.frame_start, demo.frame_end = FRAMES
    demo.frame_set(2)
    demo.render.filepath = str(tmp_path / "render" / "f_")
    demo.render.image_settings.file_format = "PNG"
    demo.sss_settings.apply_on_render = True
    demo.sss_settings.warmup_frames = 0
    return demo


def _warm_up(scene, frames: int) -> None:
    """``frames`` warm-up frames before an animation, with a method that uses them (a
    temporal one: the others' first frame gains too little to pay for the renders)."""
    scene.sss_settings.method = "as_ocv_t"
    scene.sss_settings.warmup_frames = frames


def _reference(
    scene, out: Path, warmup: int = 0, frames=FRAMES, engine="CYCLES"
) -> dict[int, np.ndarray]:
    """Composite of ``cvsss render`` per frame (linear RGB, top row first)."""
    method = scene.sss_settings.method
    standalone.render_sequence(
        scene,
        frames,
        out,
        [method],
        engine=engine,
        reference=False,
        log=None,
        warmup_frames=warmup,
    )
    return {
        f: read_result(out / method / f"{f:04d}.exr")["Composite"]
        for f in range(frames[0], frames[1] + 1)
    }


def _image_pixels(path: Path) -> np.ndarray:
    """(H, W, 4) float pixels of an image file as Blender reads it, top row first."""
    image = bpy.data.images.load(str(path))
    try:
        width, height = image.size
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[::-1]


def _colour_managed(scene, rgb: np.ndarray, path: Path) -> np.ndarray:
    """``rgb`` (linear) written with the scene's output settings, read back."""
    height, width = rgb.shape[:2]
    image = bpy.data.images.new("expected", width, height, alpha=True, float_buffer=True)
    rgba = np.ones((height, width, 4), np.float32)
    rgba[..., :3] = rgb
    image.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).reshape(-1))
    image.save_render(str(path), scene=scene)
    bpy.data.images.remove(image)
    return _image_pixels(path)


def _exr_rgba(path: Path) -> np.ndarray:
    exr = OpenEXR.File(str(path), separate_channels=True)
    channels = {k: np.asarray(c.pixels) for p in exr.parts for k, c in p.channels.items()}
    return np.stack([channels[c] for c in "RGBA"], axis=-1)


def _frame_paths(scene) -> dict[int, Path]:
    return {f: Path(scene.render.frame_path(frame=f)) for f in range(FRAMES[0], FRAMES[1] + 1)}


def _result_engines() -> list:
    """The :class:`ResultEngine` instances alive: an engine Blender kept after a
    render (Persistent Data), with its depsgraph."""
    gc.collect()
    return [o for o in gc.get_objects() if isinstance(o, ResultEngine)]


def test_png_animation_equals_cvsss_render(scene, tmp_path, snapshot):
    scene_state, state_diff = snapshot
    assert scene.render.use_persistent_data  # the demo's setting, copied by the output scene
    expected = _reference(scene, tmp_path / "ref")
    before = scene_state(scene)
    scenes = {s.name for s in bpy.data.scenes}
    began = time.perf_counter()
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    print(f"3 frames at 48x27 with Apply on Render: {time.perf_counter() - began:.2f} s")
    assert state_diff(before, scene_state(scene)) == []
    assert {s.name for s in bpy.data.scenes} == scenes
    assert active_session() is None
    # The removed output scene left no engine (and depsgraph pointing at it) behind.
    assert _result_engines() == []
    paths = _frame_paths(scene)
    assert sorted(p.name for p in paths[1].parent.iterdir()) == [p.name for p in paths.values()]
    for frame, path in paths.items():
        want = _colour_managed(scene, expected[frame], tmp_path / f"want{frame}.png")
        got = _image_pixels(path)
        # Blender's writer dithers, save_render does not: at most one 8-bit step apart.
        assert np.abs(got - want).max() <= 1 / 255 + 1e-6, frame
    # The maps of the last frame are in the image datablocks, as after Render Sequence.
    result = np.empty(48 * 27 * 4, np.float32)
    bpy.data.images["SSS Result"].pixels.foreach_get(result)
    np.testing.assert_allclose(result.reshape(27, 48, 4)[::-1, :, :3], expected[3], atol=1e-6)
    assert scene.sss_settings.last_frame == 3


def test_exr_animation_is_linear_and_equal(scene, tmp_path):
    expected = _reference(scene, tmp_path / "ref")
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    settings.color_mode = "RGBA"
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    for frame, path in _frame_paths(scene).items():
        assert path.suffix == ".exr"
        got = _exr_rgba(path)
        np.testing.assert_allclose(got[..., :3], expected[frame], rtol=1e-6, atol=1e-7)
        np.testing.assert_array_equal(got[..., 3], 1.0)


def test_off_renders_as_without_the_add_on(scene, tmp_path):
    scene.sss_settings.apply_on_render = False
    scene.render.filepath = str(tmp_path / "off" / "f_")
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    before = {name: list(getattr(bpy.app.handlers, name)) for name in handlers._HANDLERS}
    try:
        apply_on_render.unregister()
        scene.render.filepath = str(tmp_path / "plain" / "f_")
        assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    finally:
        apply_on_render.register()
    assert {n: list(getattr(bpy.app.handlers, n)) for n in handlers._HANDLERS} == before
    for frame in range(FRAMES[0], FRAMES[1] + 1):
        name = f"f_{frame:04d}.png"
        np.testing.assert_array_equal(
            _image_pixels(tmp_path / "off" / name), _image_pixels(tmp_path / "plain" / name)
        )


def test_warm_up_matches_cvsss_render_warm_up(scene, tmp_path, capfd):
    _warm_up(scene, 2)
    expected = _reference(scene, tmp_path / "ref", warmup=2)
    cold = _reference(scene, tmp_path / "cold")
    assert not np.array_equal(expected[1], cold[1])  # the warm-up changes frame 1
    capfd.readouterr()
    began = time.perf_counter()
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    seconds = time.perf_counter() - began
    out = capfd.readouterr().out
    lines = [line for line in out.splitlines() if line.startswith("cvsss: warm-up frame")]
    assert [line.split()[3] for line in lines] == ["-1", "0"]
    print(f"3 frames + 2 warm-up frames at 48x27: {seconds:.2f} s;", *lines, sep="\n")
    for frame, path in _frame_paths(scene).items():
        want = _colour_managed(scene, expected[frame], tmp_path / f"want{frame}.png")
        assert np.abs(_image_pixels(path) - want).max() <= 1 / 255 + 1e-6, frame


#: Frames of the driver tests: the scene's and its two warm-up frames before them.
WARMED = range(FRAMES[0] - 2, FRAMES[1] + 1)


def _sun_strength(frame: int) -> float:
    """The sun strength (W/m²) the driver tests give the flash demo at ``frame``."""
    return 2.0 + 1.5 * frame


def _drive_sun(scene, how: str) -> None:
    """The flash demo's sun strength as :func:`_sun_strength`: ``"keys"`` a key on every
    frame of WARMED, ``"scene_frame"`` a driver reading the scene's Current Frame
    through a variable, ``"python"`` a driver whose expression needs Python."""
    sun = bpy.data.lights["flash Sun"]
    sun.animation_data_clear()
    if how == "keys":
        for frame in WARMED:
            sun.energy = _sun_strength(frame)
            sun.keyframe_insert("energy", frame=frame)
        return
    driver = sun.driver_add("energy").driver
    driver.type = "SCRIPTED"
    if how == "scene_frame":
        var = driver.variables.new()
        var.name, var.type = "f", "SINGLE_PROP"
        var.targets[0].id_type, var.targets[0].id = "SCENE", scene
        var.targets[0].data_path = "frame_current"
        driver.expression = "2 + 1.5 * f"
    else:
        driver.expression = "2 + 1.5 * __import__('math').floor(frame)"


def _apply_on_render(scene, folder: Path) -> dict[int, np.ndarray]:
    """Apply on Render of FRAMES with 2 warm-up frames into 32-bit EXRs: RGB per frame."""
    _warm_up(scene, 2)
    scene.render.filepath = str(folder / "f_")
    settings = scene.render.image_settings
    settings.file_format, settings.color_depth = "OPEN_EXR", "32"
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    return {f: _exr_rgba(p)[..., :3] for f, p in _frame_paths(scene).items()}


def test_warm_up_frames_get_the_driver_values_of_their_frame(scene, tmp_path):
    """Warm-up frames render a copy of the scene; drivers of the data it shares with the
    user's scene read that scene, which is at the warm-up frame too (as in Blender's own
    render of that frame). Before, a driver on the scene's Current Frame read the first
    frame's number at every warm-up frame (the finished frames differed by about 0.02)."""
    _drive_sun(scene, "keys")
    keyed = _apply_on_render(scene, tmp_path / "keys")
    _drive_sun(scene, "scene_frame")
    for frame in WARMED:  # the driver gives the strength of each frame, warm-up ones too
        scene.frame_set(frame)
        assert bpy.data.lights["flash Sun"].energy == pytest.approx(_sun_strength(frame), 1e-6)
    scene.frame_set(2)
    driven = _apply_on_render(scene, tmp_path / "driven")
    assert scene.frame_current == 2
    for frame in keyed:
        np.testing.assert_allclose(driven[frame], keyed[frame], rtol=0, atol=1e-4)
    # cvsss render's warm-up (the scene itself at each frame) agrees.
    reference = _reference(scene, tmp_path / "ref", warmup=2)
    for frame in keyed:
        np.testing.assert_allclose(reference[frame], keyed[frame], rtol=0, atol=1e-4)


def test_python_drivers_follow_blenders_auto_run(scene, tmp_path, capfd):
    """The nested renders run a file's Python drivers exactly when Blender's own render
    does: trusted file (``open_mainfile(use_scripts=True)``, ``blender -y``) or not."""
    _drive_sun(scene, "keys")
    keyed = _apply_on_render(scene, tmp_path / "keys")
    _warm_up(scene, 2)
    bpy.data.lights["flash Sun"].animation_data_clear()
    bpy.data.lights["flash Sun"].energy = 0.0  # what a skipped driver gives
    dark = _apply_on_render(scene, tmp_path / "dark")
    _drive_sun(scene, "python")
    blend = tmp_path / "python.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    try:
        for trusted in (False, True):
            bpy.ops.wm.open_mainfile(filepath=str(blend), use_scripts=trusted)
            capfd.readouterr()
            got = _apply_on_render(bpy.context.scene, tmp_path / f"trusted-{trusted}")
            skipped = [ln for ln in capfd.readouterr().out.splitlines() if "auto-exec" in ln]
            want = keyed if trusted else dark
            for frame in want:
                np.testing.assert_allclose(got[frame], want[frame], rtol=0, atol=1e-4)
            assert (
                skipped == []
                if trusted
                else [
                    "cvsss: warning: Python auto-execution is off: 1 Python driver(s) (flash Sun: "
                    "energy) are not run; trust the file (blender -y, or Auto Run Python Scripts) "
                    "to run them"
                ]
            )
    finally:
        # Files opened from now on follow the (factory) preference again: not trusted.
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    probe = bpy.data.objects.new("probe", None)
    bpy.context.scene.collection.objects.link(probe)
    probe.driver_add("location", 0).driver.expression = "__import__('math').floor(frame)"
    bpy.context.scene.frame_set(3)
    assert not probe.animation_data.drivers[0].driver.is_valid


def test_still_writes_and_shows_the_finished_frame(scene, tmp_path, snapshot, capfd):
    scene_state, state_diff = snapshot
    scene.frame_set(1)
    expected = _reference(scene, tmp_path / "ref")[1]
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    before = scene_state(scene)
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    assert state_diff(before, scene_state(scene)) == []
    # Blender's still rule: the output path and the extension, no frame number.
    still = Path(scene.render.filepath + ".exr")
    assert sorted(p.name for p in still.parent.iterdir()) == [still.name]
    np.testing.assert_allclose(_exr_rgba(still)[..., :3], expected, rtol=1e-6, atol=1e-7)
    # The last log line counts the still (it said 0 delivered frames before).
    lines = [line for line in capfd.readouterr().out.splitlines() if line.startswith("cvsss: ")]
    assert lines[-1].startswith("cvsss: done: 1 frame(s) delivered in "), lines
    # F12: nothing written, the Render Result is the finished frame.
    assert bpy.ops.render.render() == {"FINISHED"}
    lines = [line for line in capfd.readouterr().out.splitlines() if line.startswith("cvsss: ")]
    assert lines[-1].startswith("cvsss: done: 1 frame(s) delivered in "), lines
    saved = tmp_path / "render_result.exr"
    bpy.data.images["Render Result"].save_render(str(saved), scene=scene)
    np.testing.assert_allclose(_exr_rgba(saved)[..., :3], expected, rtol=1e-6, atol=1e-7)
    assert state_diff(before, scene_state(scene)) == []


def test_error_and_cancel_restore_everything(scene, tmp_path, snapshot, monkeypatch):
    scene_state, state_diff = snapshot
    before = scene_state(scene)
    scenes = {s.name for s in bpy.data.scenes}

    def broken(self, frame, path):
        raise OSError("injected")

    monkeypatch.setattr(Session, "_read", broken)
    with pytest.raises(RuntimeError):  # Blender cancels: its next write fails on purpose
        bpy.ops.render.render(animation=True)
    assert state_diff(before, scene_state(scene)) == []
    assert {s.name for s in bpy.data.scenes} == scenes
    assert active_session() is None
    assert not Path(scene.render.frame_path(frame=1)).parent.exists()
    monkeypatch.undo()

    # Cancelled right after it began (Esc during the first frame).
    handlers.on_render_init(scene)
    session = active_session()
    assert scene.render.image_settings.file_format == "OPEN_EXR_MULTILAYER"
    handlers.on_render_pre(scene)
    handlers.on_render_cancel(scene)
    assert active_session() is None
    assert state_diff(before, scene_state(scene)) == []
    assert not session.folder.exists()


@pytest.fixture
def ui(monkeypatch):
    """The handlers behave as on Blender's render thread (F12 in the UI): they only switch
    the settings and queue frames; sss.finish_render does the rest afterwards."""
    monkeypatch.setattr(handlers, "_on_render_thread", lambda: True)


def test_ui_finishes_after_the_render_job(scene, tmp_path, snapshot, ui):
    scene_state, state_diff = snapshot
    _warm_up(scene, 1)
    expected = _reference(scene, tmp_path / "ref", warmup=1)
    before = scene_state(scene)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    # Blender's job is over: passes rendered, nothing delivered, the scene still switched.
    assert not (tmp_path / "render").exists()
    assert scene.render.image_settings.file_format == "OPEN_EXR_MULTILAYER"
    handlers._poll()  # the UI's timer: the job is over, so it finishes (no window here)
    assert state_diff(before, scene_state(scene)) == []
    assert active_session() is None
    for frame, path in _frame_paths(scene).items():
        want = _colour_managed(scene, expected[frame], tmp_path / f"want{frame}.png")
        assert np.abs(_image_pixels(path) - want).max() <= 1 / 255 + 1e-6, frame
    # The Render Result shows the last finished frame.
    saved = tmp_path / "render_result.png"
    bpy.data.images["Render Result"].save_render(str(saved), scene=scene)
    want = _colour_managed(scene, expected[3], tmp_path / "want_rr.png")
    assert np.abs(_image_pixels(saved) - want).max() <= 1 / 255 + 1e-6


def test_ui_f12_shows_the_finished_frame(scene, tmp_path, snapshot, ui):
    scene_state, state_diff = snapshot
    scene.frame_set(1)
    expected = _reference(scene, tmp_path / "ref")[1]
    before = scene_state(scene)
    assert bpy.ops.render.render() == {"FINISHED"}  # F12: nothing is written
    assert bpy.ops.sss.finish_render() == {"FINISHED"}
    assert state_diff(before, scene_state(scene)) == []
    assert not (tmp_path / "render").exists()
    saved = tmp_path / "render_result.png"
    bpy.data.images["Render Result"].save_render(str(saved), scene=scene)
    want = _colour_managed(scene, expected, tmp_path / "want.png")
    assert np.abs(_image_pixels(saved) - want).max() <= 1 / 255 + 1e-6


def test_ui_finishing_says_it_compiles_the_kernels_first(
    scene, tmp_path, snapshot, ui, no_compile, slow_compile
):
    """F12 in the UI where the kernels are not compiled yet: the finishing steps show it in
    the status bar for one tick, then compile them (after Blender's render, nothing
    beside) and process the frame."""
    scene_state, state_diff = snapshot
    scene.frame_set(1)
    expected = _reference(scene, tmp_path / "ref")[1]
    no_compile.clear()  # the reference's job prepared them: start afresh
    calls = slow_compile(0.2)
    before = scene_state(scene)
    assert bpy.ops.render.render() == {"FINISHED"}
    rendered = time.perf_counter()
    assert calls == []  # nothing beside Blender's render
    steps = list(active_session().finish_steps())
    assert steps[0] == precompile.COMPILING_STATUS and steps[1].startswith("frame 1 "), steps
    assert calls == [(48 * 27, "cvsss-compile")] and rendered < no_compile["began"]
    assert state_diff(before, scene_state(scene)) == []
    saved = tmp_path / "render_result.png"
    bpy.data.images["Render Result"].save_render(str(saved), scene=scene)
    want = _colour_managed(scene, expected, tmp_path / "want.png")
    assert np.abs(_image_pixels(saved) - want).max() <= 1 / 255 + 1e-6


def test_ui_escape_restores_and_keeps_written_frames(scene, tmp_path, snapshot, ui):
    scene_state, state_diff = snapshot
    before = scene_state(scene)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    steps = active_session().finish_steps()
    texts = [next(steps) for _ in range(4)]  # three frames processed, the first written
    assert texts[-1].startswith("frame 1 -> ")
    steps.close()  # Esc
    assert active_session() is None
    assert state_diff(before, scene_state(scene)) == []
    assert [p.name for p in (tmp_path / "render").iterdir()] == ["f_0001.png"]


def test_ui_save_while_finishing_saves_the_users_scene(scene, tmp_path, snapshot, ui):
    """Ctrl-S between the finishing steps (the UI is live then): every saved file holds the
    user's scene, not the pass configuration or the add-on's temporary scenes, and the
    frames come out as without the saves."""
    scene_state, state_diff = snapshot
    _warm_up(scene, 1)
    expected = _reference(scene, tmp_path / "ref", warmup=1)
    before = scene_state(scene)
    scenes = sorted(s.name for s in bpy.data.scenes)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    saved = []
    for text in active_session().finish_steps():
        path = tmp_path / f"saved{len(saved)}.blend"
        assert bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True) == {"FINISHED"}
        saved.append((path, text))
    assert len(saved) >= 7  # the warm-up, three frames, three deliveries, the display
    assert active_session() is None
    assert state_diff(before, scene_state(scene)) == []
    for frame, path in _frame_paths(scene).items():
        want = _colour_managed(scene, expected[frame], tmp_path / f"want{frame}.png")
        assert np.abs(_image_pixels(path) - want).max() <= 1 / 255 + 1e-6, frame
    name = scene.name
    for path, text in saved:
        bpy.ops.wm.open_mainfile(filepath=str(path))
        assert sorted(s.name for s in bpy.data.scenes) == scenes, text
        diff = state_diff(before, scene_state(bpy.data.scenes[name]))
        assert [d for d in diff if ".image: " not in d] == [], text


def test_ui_reports_an_error_met_while_blender_rendered(scene, tmp_path, snapshot, ui, monkeypatch):
    """An error in a handler on the render thread at the last frame cannot stop Blender's
    render any more: the finishing operator reports it, and restores the scene."""
    scene_state, state_diff = snapshot
    before = scene_state(scene)
    written = Session.frame_written

    def broken(self, frame):
        if frame == FRAMES[1]:
            raise OSError("injected")
        written(self, frame)

    monkeypatch.setattr(Session, "frame_written", broken)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    with pytest.raises(RuntimeError, match="frame 3: OSError: injected"):
        bpy.ops.sss.finish_render()
    assert active_session() is None
    assert state_diff(before, scene_state(scene)) == []
    assert not (tmp_path / "render").exists()


def test_background_error_at_the_last_frame_is_the_last_line(
    scene, tmp_path, snapshot, capfd, monkeypatch
):
    """In background mode nothing can fail Blender's render after its last write: the frame
    is not delivered, and cvsss's last line says why (README, Apply on Render, *Limits*)."""
    scene_state, state_diff = snapshot
    before = scene_state(scene)
    original = Session.process_next

    def broken(self):
        if self.still or self.pending[0][0] == FRAMES[1]:
            raise OSError("injected")
        return original(self)

    monkeypatch.setattr(Session, "process_next", broken)
    bpy.ops.render.render(animation=True)
    assert state_diff(before, scene_state(scene)) == []
    assert sorted(p.name for p in (tmp_path / "render").iterdir()) == ["f_0001.png", "f_0002.png"]
    lines = [line for line in capfd.readouterr().out.splitlines() if line.startswith("cvsss: ")]
    assert lines[-1].startswith("cvsss: stopped after 2 delivered frame(s): frame 3: OSError")

    # A still (-f, F12 with write_still): the same, where it said "done" before.
    scene.frame_set(1)
    before = scene_state(scene)
    bpy.ops.render.render(write_still=True)
    assert state_diff(before, scene_state(scene)) == []
    lines = [line for line in capfd.readouterr().out.splitlines() if line.startswith("cvsss: ")]
    assert lines[-1] == "cvsss: stopped after 0 delivered frame(s): OSError: injected", lines
    assert active_session() is None


def test_frame_by_frame_renders_continue_the_history(scene, tmp_path):
    """``blender -b -f 1..3`` renders one frame per call: the history goes on."""
    _warm_up(scene, 1)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    whole = {f: _image_pixels(p) for f, p in _frame_paths(scene).items()}
    scene.render.filepath = str(tmp_path / "single" / "f_")
    for frame in range(FRAMES[0], FRAMES[1] + 1):
        scene.frame_start = scene.frame_end = frame
        assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    for frame, pixels in whole.items():
        single = _image_pixels(tmp_path / "single" / f"f_{frame:04d}.png")
        np.testing.assert_array_equal(single, pixels)


def test_a_delivered_frames_temporary_files_are_gone(scene, tmp_path):
    """Once a frame is written, its pass file, sidecar and finished frame leave the
    temporary folder (a warm-up frame's once the history has it): a long animation does
    not keep every frame's passes on disk until it ends."""
    _warm_up(scene, 1)
    seen = {}

    def look(_scene, _depsgraph=None):  # runs after the add-on's render_write handler
        if _scene != scene:
            return  # the warm-up frame's render, of a copy of the scene
        session = active_session()
        seen[_scene.frame_current] = sorted(
            p.name for folder in (session.passes, session.final) for p in folder.iterdir()
        )

    bpy.app.handlers.render_write.append(look)
    try:
        assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    finally:
        bpy.app.handlers.render_write.remove(look)
    assert seen == {1: [], 2: [], 3: []}
    assert all(p.is_file() for p in _frame_paths(scene).values())


def test_the_vector_pass_is_rendered_for_temporal_methods_only(scene, tmp_path):
    """Only a temporal method moves last frame's estimates along the motion vectors;
    for the others the pass render leaves the Vector pass out (the engine evaluates the
    scene at the neighbouring frames for it). The user's own Vector pass stays where a
    multilayer file (or a compositor) takes the view layer's passes."""
    layer = scene.view_layers[0]
    seen = {}

    def look(_scene, _depsgraph=None):  # runs after the add-on's render_pre handler
        if _scene == scene:
            seen.setdefault(scene.sss_settings.method, set()).add(layer.use_pass_vector)

    layer.use_pass_vector = False
    bpy.app.handlers.render_pre.append(look)
    try:
        for method in ("as_ccv", "as_ccv_t", "fixed"):
            scene.sss_settings.method = method
            scene.render.filepath = str(tmp_path / method / "f_")
            assert bpy.ops.render.render(animation=True) == {"FINISHED"}
        layer.use_pass_vector = True  # the user's, for the multilayer file
        settings = scene.render.image_settings
        settings.media_type = "MULTI_LAYER_IMAGE"
        settings.file_format = "OPEN_EXR_MULTILAYER"
        scene.sss_settings.method = "as_ccv"
        scene.render.filepath = str(tmp_path / "user" / "f_")
        seen.pop("as_ccv")
        assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    finally:
        bpy.app.handlers.render_pre.remove(look)
    assert seen == {"as_ccv_t": {True}, "fixed": {False}, "as_ccv": {True}}
    assert layer.use_pass_vector  # the user's setting back


def test_overwrite_off_and_placeholders_as_blender(scene, tmp_path):
    scene.render.use_overwrite = False
    scene.render.use_placeholder = True
    kept = Path(scene.render.frame_path(frame=2))
    kept.parent.mkdir(parents=True)
    kept.write_bytes(b"another machine's frame")
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    assert kept.read_bytes() == b"another machine's frame"
    for frame in (1, 3):
        assert _image_pixels(Path(scene.render.frame_path(frame=frame))).shape == (27, 48, 4)


def test_user_errors_stop_the_render_with_a_message(scene, tmp_path, snapshot):
    scene_state, state_diff = snapshot
    scene.render.engine = "BLENDER_WORKBENCH"
    before = scene_state(scene)
    with pytest.raises(RuntimeError, match="needs Cycles or EEVEE"):
        bpy.ops.render.render(animation=True)
    assert state_diff(before, scene_state(scene)) == []
    assert not Path(scene.render.filepath).parent.exists()


def test_movie_is_encoded_with_blenders_writer(scene, tmp_path):
    scene.render.resolution_y = 28  # H.264 wants even sizes
    settings = scene.render.image_settings
    settings.media_type = "VIDEO"
    settings.file_format = "FFMPEG"
    scene.render.ffmpeg.format = "MPEG4"
    scene.render.ffmpeg.codec = "H264"
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    movie = Path(scene.render.frame_path(frame=FRAMES[0]))
    assert movie.name == "f_0001-0003.mp4" and movie.stat().st_size > 0
    clip = bpy.data.movieclips.load(str(movie))
    assert clip.frame_duration == 3
    bpy.data.movieclips.remove(clip)


def test_blender_b_renders_a_blend_with_apply_on_render(
    scene, tmp_path, extension_zip, check_script
):
    """``blender -b scene.blend -a`` with the extension installed from its zip (bpy module)."""
    _warm_up(scene, 1)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}  # here, for comparison
    here = _frame_paths(scene)
    scene.render.filepath = str(tmp_path / "farm" / "f_")
    # The installed copy samples with NumPy: the same samples as the compiled passes here
    # (to float32 rounding), without a cold compile of its own, which the next test makes.
    scene.sss_settings.backend = "numpy"
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    report, stdout = check_script(
        "apply_on_render_check.py", extension_zip, tmp_path / "work", blend, cwd=tmp_path
    )
    assert report["install"] == ["FINISHED"] and report["render"] == ["FINISHED"]
    assert report["apply_on_render"] and report["scenes"] == ["Scene"]
    assert report["file_format"] == "PNG"
    # Quiet, useful progress: one line per frame, no word of the temporary pass files.
    lines = stdout.splitlines()
    assert [ln.split()[1:3] for ln in lines if ln.startswith("cvsss: frame")] == [
        ["frame", "1"],
        ["frame", "2"],
        ["frame", "3"],
    ]
    assert not [ln for ln in lines if "Saved:" in ln or "cvsss-render-" in ln]
    for path in here.values():
        farm = tmp_path / "farm" / path.name
        assert np.abs(_image_pixels(farm) - _image_pixels(path)).max() <= 1 / 255 + 1e-6


def test_installed_extension_compiles_the_kernels_beside_blenders_render(
    scene, tmp_path, extension_zip, check_script, monkeypatch, thick_parts
):
    """The first render on a machine (an empty numba cache), with the extension installed
    from its zip under Blender's package name: a process of its own starts compiling
    before Blender renders, the first frame's post-process waits only for its frame
    size's build and loads it from the cache (no compile in Blender's process), and the
    process goes on to stamp the cache complete. About a minute: a real cold compile."""
    thick_parts()  # no part goes to Cycles whole: the log has no note line
    scene.frame_end = scene.frame_start  # one frame
    scene.render.filepath = str(tmp_path / "farm" / "f_")
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    monkeypatch.setenv("CVSSS_BACKGROUND_COMPILE", "1")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "numba"))
    report, stdout = check_script(
        "apply_on_render_check.py", extension_zip, tmp_path / "work", blend, cwd=tmp_path
    )
    assert report["render"] == ["FINISHED"]
    background = report["background"]
    assert background is not None, stdout[-3000:]
    assert background["package"] == "bl_ext.cvsss_test.cvsss"
    assert background["args"] == [background["package"], str(48 * 27)]
    assert background["exit"] == 0 and background["stamped"]
    # 48×27 frames take the serial build: loaded, not compiled, in Blender's process.
    assert background["builds"] == {"pixel_sums": [0, 0], "pixel_sums_serial": [1, 0]}
    # Started when the render began (render_init), before the frame was rendered; the
    # post-process waited for it, then loaded.
    lines = [ln.removeprefix("cvsss: ") for ln in stdout.splitlines() if ln.startswith("cvsss:")]
    assert (
        lines[1] == "compiling the numba passes in a background process (first use on this machine)"
    )
    assert lines[-3].startswith("the numba passes were compiled in the background in "), lines
    assert lines[-2].startswith("frame 1 as_ocv:"), lines
    assert Path(tmp_path / "farm" / "f_0001.png").is_file()


@pytest.mark.slow
def test_eevee_passes_on_one_frame(scene, tmp_path):
    """The same path with EEVEE (software GL here: most of the time is shader compilation)."""
    scene.render.engine = "BLENDER_EEVEE"
    scene.frame_start = scene.frame_end = 1
    began = time.perf_counter()
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    print(f"EEVEE, one 48x27 frame with Apply on Render: {time.perf_counter() - began:.1f} s")
    assert scene.render.engine == "BLENDER_EEVEE"
    got = _image_pixels(Path(scene.render.frame_path(frame=1)))
    expected = _reference(scene, tmp_path / "ref", frames=(1, 1), engine="EEVEE")[1]
    want = _colour_managed(scene, expected, tmp_path / "want.png")
    assert np.abs(got - want).max() <= 1 / 255 + 1e-6
