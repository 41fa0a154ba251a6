"""core.geometry: what the sampling step's inputs are made of."""

from __future__ import annotations

import numpy as np
import pytest

from cvsss.core.frame import compact_slots


@pytest.mark.parametrize(
    "keys",
    [[1], [3, 7], [1, 2, 5, 65535], [2, 65536], [7, 2**31 - 1], [0, 4]],
)
@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.uint32, np.uint64, np.uint8])
def test_compact_slots_maps_keys_to_their_rank_and_anything_else_to_zero(keys, dtype):
    """The lookup table (keys 1…65535, index types) and the binary search (other keys,
    uint64) give the same slots: ``keys[i]`` → i + 1, every other value → 0, including
    values above the largest key, negative ones and the Material Index pass's largest,
    2³¹ − 1."""
    keys = np.array(keys, dtype=np.int64)
    rng = np.random.default_rng(0)
    values = np.concatenate(
        [keys, keys + 1, keys - 1, [0, 1, 2, 65535, 65536, 2**31 - 1], rng.integers(0, 70000, 500)]
    )
    if np.dtype(dtype).kind == "i":
        values = np.concatenate([values, [-1, -70000]])
    values = values[(values >= np.iinfo(dtype).min) & (values <= np.iinfo(dtype).max)]
    material = values.astype(dtype).reshape(-1, 2 if values.size % 2 == 0 else 1)
    slots = compact_slots(material, keys)
    assert slots.dtype == np.int32 and slots.shape == material.shape
    rank = {int(k): i + 1 for i, k in enumerate(keys)}
    expected = np.array([rank.get(int(v), 0) for v in material.reshape(-1)]).reshape(slots.shape)
    assert np.array_equal(slots, expected)


def test_compact_slots_without_subsurface_materials_is_all_zero():
    assert not compact_slots(np.arange(10, dtype=np.int32), np.zeros(0, np.int64)).any()


# -- GeometryCache: a still scene's geometry, reused -------------------------------------
def _geometry_fields_equal(a, b) -> bool:
    """Every field of two Geometries holds the same values (arrays: same dtype and bits)."""
    import dataclasses

    from cvsss.core.geometry import Geometry

    for f in dataclasses.fields(Geometry):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "surface" and x is not None and y is not None:
            same = (
                (x.ortho, x.unit, x.centre) == (y.ortho, y.unit, y.centre)
                and np.array_equal(x.area.view(np.uint32), y.area.view(np.uint32))
                and np.array_equal(x.normal.view(np.uint32), y.normal.view(np.uint32))
            )
        elif isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            same = (
                isinstance(x, np.ndarray)
                and isinstance(y, np.ndarray)
                and x.dtype == y.dtype
                and x.shape == y.shape
                and np.array_equal(x.view(np.uint8), y.view(np.uint8))
            )
        else:
            same = x == y
        if not same:
            return False
    return True


def _lit_frames(n: int = 3):
    """Frames 1…n of the flash sequence (only the lights change) with an Object Index,
    a per-pixel Subsurface Weight and an indirect pass that change from frame to frame."""
    import dataclasses

    from cvsss.core.synthetic import scene_frame

    frames = []
    for k in range(1, n + 1):
        f = scene_frame("flash", k, 48, 32)
        rng = np.random.default_rng(k)
        weight = rng.uniform(0.0, 1.0, f.shape).astype(np.float32)
        weight[rng.random(f.shape) < 0.3] = np.nan  # the material's weight there
        frames.append(
            dataclasses.replace(
                f,
                objects=(np.arange(f.shape[1]) // 24).astype(np.int32)[None].repeat(f.shape[0], 0),
                sss_weight=weight,
                indirect=(0.3 * k * f.lighting).astype(np.float32),
            )
        )
    return frames


@pytest.mark.parametrize("backend", ["numpy", "auto"])
def test_geometry_cache_reuses_a_still_scene_bit_for_bit(backend):
    """Frames whose geometry passes do not change (the flash sequence) are served from
    the cache: every field equals geometry_of()'s of that frame, bit for bit, including the
    lighting-dependent direct part and the Subsurface Weight, which change each frame."""
    from cvsss.core.geometry import GeometryCache, geometry_of
    from cvsss.core.params import SSSParams
    from cvsss.core.profiles.factory import ProfileCache

    frames = _lit_frames(3)
    profiles = ProfileCache(SSSParams())
    cache = GeometryCache()
    options = dict(surface_distance=True, core_only=True, backend=backend)
    directs, images = [], []
    for f in frames:
        profile = profiles.get(f)
        geom = cache.get(f, profile, **options)
        fresh = geometry_of(f, profile, **options)
        assert _geometry_fields_equal(geom, fresh)
        directs.append(geom.direct)
        # The γ and mask images: made once, read-only, handed on to the hits.
        gamma, mask = geom.gamma_image(backend), geom.mask_image
        assert np.array_equal(gamma, fresh.to_image(fresh.gamma)) and gamma.dtype == np.float32
        assert np.array_equal(mask, fresh.mask())
        assert not gamma.flags.writeable and not mask.flags.writeable
        images.append((gamma, mask))
    assert cache.hits == 2
    assert not np.array_equal(directs[0], directs[1])  # taken from each frame's passes
    assert images[2][0] is images[0][0] and images[2][1] is images[0][1]


def test_geometry_cache_prepares_anew_when_geometry_changes():
    """A changed pass (one depth value, one Material Index, one
    Object Index), camera, crop, material table, profile or option is a miss: the
    result is geometry_of()'s of the new frame."""
    import dataclasses

    from cvsss.core.frame import Crop
    from cvsss.core.geometry import GeometryCache, geometry_of
    from cvsss.core.params import SSSParams
    from cvsss.core.profiles.factory import ProfileCache

    base = _lit_frames(1)[0]
    profiles = ProfileCache(SSSParams())
    profile = profiles.get(base)

    def changed(**kw):
        return dataclasses.replace(base, **kw)

    depth = base.depth.copy()
    depth[10, 20] *= 1.01
    material = base.material.copy()
    material[12, 24] = 0
    objects = base.objects.copy()
    objects[12, 24] += 1
    cam = base.camera
    h, w = base.shape
    cases = [
        (changed(depth=depth), {}),
        (changed(material=material), {}),
        (changed(objects=objects), {}),
        (changed(objects=None), {}),
        (changed(camera=dataclasses.replace(cam, lens=cam.lens * 1.1)), {}),
        (changed(crop=Crop(image=(h, w), origin=(0, 0), core=(0, h, 0, w // 2))), {}),
        (changed(materials={k: v for k, v in list(base.materials.items())[:1]}), {}),
        (base, {"surface_distance": False}),
    ]
    for frame, options in cases:
        cache = GeometryCache()
        cache.get(base, profile, surface_distance=True)
        prof = profiles.get(frame)
        geom = cache.get(frame, prof, **{"surface_distance": True, **options})
        assert cache.hits == 0
        assert _geometry_fields_equal(
            geom, geometry_of(frame, prof, **{"surface_distance": True, **options})
        )
    # The same materials with a new profile object (another ProfileCache) is a miss too.
    cache = GeometryCache()
    cache.get(base, profile)
    cache.get(base, ProfileCache(SSSParams()).get(base))
    assert cache.hits == 0


def test_geometry_cache_keeps_its_own_copy_of_the_passes():
    """Writing into the previous frame's depth array after it was prepared (a reader
    that reuses its buffers) does not make the next frame a false hit."""
    from cvsss.core.geometry import GeometryCache, geometry_of
    from cvsss.core.params import SSSParams
    from cvsss.core.profiles.factory import ProfileCache

    frame = _lit_frames(1)[0]
    profile = ProfileCache(SSSParams()).get(frame)
    cache = GeometryCache()
    cache.get(frame, profile)
    frame.depth[5:9, 5:40] = 2.5  # the buffer now holds the next frame's depth
    geom = cache.get(frame, profile)
    assert cache.hits == 0
    assert _geometry_fields_equal(geom, geometry_of(frame, profile))


def test_geometry_cache_bounds_its_entries_and_keeps_the_newest():
    """One entry per crop, the oldest dropped beyond MAX_ENTRIES or MAX_BYTES; the newest
    is kept even when it alone is larger than MAX_BYTES (a whole frame still hits)."""
    import dataclasses

    from cvsss.core.frame import Crop
    from cvsss.core.geometry import GeometryCache, _entry_bytes, geometry_of
    from cvsss.core.params import SSSParams
    from cvsss.core.profiles.factory import ProfileCache

    base = _lit_frames(1)[0]
    profile = ProfileCache(SSSParams()).get(base)
    h, w = base.shape
    crops = [
        dataclasses.replace(base, crop=Crop(image=(h, w), origin=(0, 0), core=(0, h, x, x + 16)))
        for x in (0, 16, 32)
    ]
    cache = GeometryCache()
    for f in crops + crops:
        cache.get(f, profile, surface_distance=True)
    assert cache.hits == 3 and len(cache._entries) == 3
    sizes = [_entry_bytes(e) for e in cache._entries.values()]
    assert all(n > base.depth.nbytes for n in sizes)

    cache = GeometryCache()
    cache.MAX_BYTES = sum(sorted(sizes)[1:])  # room for any two, not three
    for f in crops + crops:
        cache.get(f, profile, surface_distance=True)
    assert cache.hits == 0 and len(cache._entries) == 2  # each came back after eviction
    cache.MAX_ENTRIES = 1
    cache.get(crops[0], profile, surface_distance=True)
    assert len(cache._entries) == 1

    cache = GeometryCache()
    cache.MAX_BYTES = 1  # smaller than any entry: the newest stays
    for _ in range(3):
        geom = cache.get(base, profile, surface_distance=True)
    assert cache.hits == 2 and len(cache._entries) == 1
    assert _geometry_fields_equal(geom, geometry_of(base, profile, surface_distance=True))


def test_light_scale_from_the_geometry_equals_the_frames_own():
    """The temporal reuse's light scale from the lighting at the whole frame's Geometry
    pixels equals the one found from the frame's passes bit for bit: background
    (infinite depth), pixels without subsurface and an unknown material index are left
    out by both."""
    import dataclasses

    from cvsss.core.geometry import geometry_of, light_scale
    from cvsss.core.params import SSSParams
    from cvsss.core.profiles.factory import ProfileCache
    from cvsss.core.synthetic import scene_frame

    f = scene_frame("flash", 2, 48, 32)
    material = f.material.copy()
    material[:, :6] = 0  # no subsurface
    material[:4, 10:20] = 99  # no such material
    depth = f.depth.copy()
    depth[-5:, 30:] = np.inf  # background
    f = dataclasses.replace(f, material=material, depth=depth)
    profile = ProfileCache(SSSParams()).get(f)
    geom = geometry_of(f, profile)
    assert 0 < geom.size < material.size
    own = light_scale(f, profile)
    from_geom = light_scale(f, profile, geom.at(f.lighting).astype(np.float64))
    assert from_geom.dtype == np.float64 and from_geom.shape == (3,)
    assert np.array_equal(own.view(np.uint64), from_geom.view(np.uint64))
    # The selection matters: the mean over every pixel differs.
    assert not np.allclose(own, f.lighting.reshape(-1, 3).mean(axis=0, dtype=np.float64))


# -- the depth-buffer surface at an object's border ---------------------------------------
@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_pixel_next_to_another_object_keeps_its_own_surfaces_normal(backend):
    """A block facing an orthographic camera (rows 0-23) stands on a table top tilted 60°
    from the view axis (rows 24-47). With the Object Index pass the top's row next to
    the block has the top's normal, (0, −sin 60°, −cos 60°) in camera space (y down,
    towards the camera), as every other row of the top; the block's bottom row, its
    own (0, 0, −1). Without the pass the step towards the block, the smaller, bends the
    top's row towards the block's normal."""
    import dataclasses

    from cvsss.core.camera import Camera
    from cvsss.core.geometry import surface
    from cvsss.core.synthetic import flat_plane

    if backend == "numba":
        pytest.importorskip("numba")
    row = np.arange(48, dtype=np.float64)[:, None]
    # The top's depth grows by tan 60° cm per row up (1 cm pixels); the block stands at
    # the top's depth where they meet (between rows 23 and 24).
    table = 2.0 + np.tan(np.radians(60.0)) * (47.5 - row) * 0.01
    depth = np.where(row < 24, 2.0 + np.tan(np.radians(60.0)) * 24.0 * 0.01, table)
    frame = dataclasses.replace(
        flat_plane(),
        camera=Camera(width=64, height=48, type="ORTHO", ortho_scale=0.64),
        depth=np.broadcast_to(depth, (48, 64)).astype(np.float32).copy(),
        objects=np.broadcast_to(np.where(row < 24, 2, 1), (48, 64)).astype(np.int32),
    )
    normal = surface(frame, backend).normal.reshape(48, 64, 3)
    top = (0.0, -np.sin(np.radians(60.0)), -np.cos(np.radians(60.0)))
    np.testing.assert_allclose(normal[24:, 1:-1], np.broadcast_to(top, (24, 62, 3)), atol=1e-5)
    np.testing.assert_allclose(normal[23, 1:-1], np.broadcast_to((0, 0, -1), (62, 3)), atol=1e-6)
    bent = surface(dataclasses.replace(frame, objects=None), backend).normal.reshape(48, 64, 3)
    assert np.abs(bent[24, 1:-1] - top).max() > 0.1
