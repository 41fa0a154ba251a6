"""Case files (JSON lines) for render_slabs.py: the fit's grid, scale checks, sensitivities.

Each channel's Subsurface Radius is chosen so that the profile it should
produce has a Burley shape of about ``--target`` pixels: from Christensen and
Burley's search-light fit ``d ≈ ℓ/s(A)`` (ℓ the walk's mean free path for the
method, :func:`cvsss.core.profiles.random_walk.mean_free_path`), so that every
albedo is resolved alike by the pixel grid. Run with the project on the path::

    python tools/random_walk/cases.py fit > fit.jsonl
    python tools/random_walk/cases.py uniform > uniform.jsonl
    python tools/random_walk/cases.py scale > scale.jsonl
    python tools/random_walk/cases.py sensitivity > sens.jsonl
    python tools/random_walk/cases.py holdout > holdout.jsonl
    python tools/random_walk/cases.py anisotropy --samples 256 > anisotropy.jsonl
    python tools/random_walk/cases.py view > view.jsonl
    python tools/random_walk/cases.py curvature --samples 512 > curvature.jsonl
    python tools/random_walk/cases.py spheres > spheres.jsonl   # needs the fitted data
    python tools/random_walk/cases.py thickness --samples 512 > thickness.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import sys

import numpy as np

from cvsss.core.profiles.random_walk import mean_free_path, search_light_scale

#: Base Colors of the fit, three per render (one per channel).
FIT_ALBEDOS = (
    0.02,
    0.05,
    0.1,
    0.15,
    0.2,
    0.25,
    0.3,
    0.35,
    0.4,
    0.5,
    0.6,
    0.7,
    0.75,
    0.8,
    0.85,
    0.9,
    0.95,
    0.98,
)
#: Subsurface Anisotropy nodes beyond 0 (Cycles clamps it to [0, 0.9]) and their albedos.
ANISOTROPIES = (0.3, 0.6, 0.9)
ANISOTROPY_ALBEDOS = (0.05, 0.1, 0.2, 0.3, 0.45, 0.6, 0.75, 0.85, 0.95)
#: Sphere radii in mean free paths, and the albedos, of the curvature grid.
CURVATURE_RADII = (3, 5, 10, 20, 50)
CURVATURE_ALBEDOS = ((0.05, 0.15, 0.3), (0.45, 0.6, 0.75), (0.85, 0.9, 0.95))
#: View angles (degrees from the normal) of the energy's view dependence.
VIEW_ANGLES = (30, 45, 60, 75, 85)
PIXEL = 0.001  # scene units
SCALE = 0.05  # Subsurface Scale
#: The demo's marble (demo_blend.scenes.preset_material("marble")): Base Color, Subsurface
#: Radius and Scale, so that the red channel's mean free path is 1 cm.
MARBLE = {"albedo": [0.7753, 0.741, 0.7076], "radius": [1.0, 0.8038, 0.672], "scale": 0.12566}
#: Slab thicknesses of the thickness cases, in the marble's red mean free paths (and a deep one).
THICKNESSES = (1, 2, 4, 5, 6, 8, 100)


def radius_for(albedo, method: str, target_px: float, subsurface_ior: float = 1.4) -> list:
    """Subsurface Radius per channel that puts the expected Burley d at ``target_px`` pixels."""
    a = np.asarray(albedo, dtype=np.float64)
    want_d = target_px * PIXEL
    if method == "BURLEY":
        ell_per_radius = mean_free_path([1, 1, 1], SCALE, a, method)
        return (want_d / ell_per_radius).round(6).tolist()
    ell_per_radius = mean_free_path([1, 1, 1], SCALE, a, method, subsurface_ior)
    return (want_d * search_light_scale(a) / ell_per_radius).round(6).tolist()


def case(name, method, albedo, target, samples, **extra) -> dict:
    out = {
        "name": name,
        "method": method,
        "albedo": [float(v) for v in albedo],
        "radius": radius_for(albedo, method, target, extra.get("subsurface_ior", 1.4)),
        "scale": SCALE,
        "pixel": PIXEL,
        "width": 256,
        "height": 32,
        "samples": samples,
        **extra,
    }
    return out


def sphere_cases(samples: int, albedo=(0.2, 0.5, 0.8), d_px: float = 3.0) -> list[dict]:
    """Spheres of 5, 10 and 20 times the largest mean free path, lit from the side, in
    each random-walk method and as Cycles' Burley with the plain d (radius as given) and
    with the fitted model (radius scaled to the model's d, Base Color to A·e)."""
    from cvsss.core.profiles.random_walk import shape

    out = []
    short = {"RANDOM_WALK": "rw", "RANDOM_WALK_SKIN": "skin"}
    for method in ("RANDOM_WALK", "RANDOM_WALK_SKIN"):
        radius = radius_for(albedo, method, d_px)
        d, e = shape(radius, SCALE, albedo, method)
        ell = mean_free_path(radius, SCALE, albedo, method)
        for k in (5, 10, 20):
            size = 128
            sphere = k * float(max(ell))
            pixel = 2.4 * sphere / size
            # 128 pixels across 2.4 sphere radii: the truth and both Burley renders see
            # the same grid, so its resolution of d matters little here.
            common = {
                "geometry": "sphere",
                "albedo": list(albedo),
                "scale": SCALE,
                "pixel": pixel,
                "width": size,
                "height": size,
                "samples": samples,
                "sphere_radius": sphere,
            }
            tag = f"{short[method]}_{k}"
            out.append(
                {"name": f"sphere_{tag}_truth", "method": method, "radius": radius, **common}
            )
            # Cycles' Burley d is radius·scale/(4π): radius for the model's d.
            fitted = (np.asarray(d) * 4 * math.pi / SCALE).round(6).tolist()
            out.append(
                {
                    "name": f"sphere_{tag}_fitted",
                    "method": "BURLEY",
                    "radius": fitted,
                    **{**common, "albedo": (np.asarray(albedo) * e).round(6).tolist()},
                }
            )
            out.append(
                {"name": f"sphere_{tag}_plain", "method": "BURLEY", "radius": radius, **common}
            )
            if k == 10:  # the truth's own noise: the same render with another seed
                out.append(
                    {
                        "name": f"sphere_{tag}_seed1",
                        "method": method,
                        "radius": radius,
                        **common,
                        "seed": 1,
                    }
                )
    return out


def triples(values):
    values = list(values)
    while len(values) % 3:
        values.append(values[-1])
    return [values[i : i + 3] for i in range(0, len(values), 3)]


def grid(kind: str, samples: int, target: float) -> list[dict]:
    out = []
    short = {"RANDOM_WALK": "rw", "RANDOM_WALK_SKIN": "skin", "BURLEY": "burley"}
    if kind == "fit":
        for method in ("RANDOM_WALK", "RANDOM_WALK_SKIN"):
            for i, alb in enumerate(triples(FIT_ALBEDOS)):
                out.append(case(f"fit_{short[method]}_{i}", method, alb, target, samples))
        out.append(case("fit_burley_0", "BURLEY", [0.1, 0.5, 0.9], target, samples))
    elif kind == "anisotropy":
        # Subsurface Anisotropy moves the profile by up to 30 % (sensitivity grid): a
        # coarser table per anisotropy node, fewer samples.
        for method in ("RANDOM_WALK", "RANDOM_WALK_SKIN"):
            for g in ANISOTROPIES:
                for i, alb in enumerate(triples(ANISOTROPY_ALBEDOS)):
                    c = case(
                        f"fit_{short[method]}_g{g:g}_{i}",
                        method,
                        alb,
                        target,
                        samples,
                        anisotropy=g,
                    )
                    out += [
                        c,
                        {
                            **c,
                            "name": c["name"].replace("fit_", "uniform_"),
                            "occluder": False,
                            "width": 32,
                            "height": 32,
                        },
                    ]
            for g in (0.45, 0.75):
                c = case(
                    f"holdout_{short[method]}_g{g:g}",
                    method,
                    [0.12, 0.45, 0.88],
                    target,
                    samples,
                    seed=7,
                    anisotropy=g,
                )
                out += [
                    c,
                    {
                        **c,
                        "name": c["name"].replace("holdout_", "holdoutuni_"),
                        "occluder": False,
                        "width": 32,
                        "height": 32,
                    },
                ]
    elif kind == "view":
        # Random-walk paths enter by refraction of the view ray: the reflectance depends
        # on the view angle (Burley's does not). The fit's materials, lit everywhere,
        # seen from VIEW_ANGLES; and a few shadow edges at 60 degrees.
        for c in grid("uniform", samples, target):
            for angle in VIEW_ANGLES:
                if c["method"] == "BURLEY" and angle != VIEW_ANGLES[-1]:
                    continue
                out.append(
                    {
                        **c,
                        "name": c["name"].replace("uniform_", f"view{angle}_"),
                        "view_angle": float(angle),
                    }
                )
        for c in grid("fit", samples, target):
            if c["name"][-1] in "135" or c["method"] == "BURLEY":
                out.append(
                    {
                        **c,
                        "name": c["name"].replace("fit_", "edge60_"),
                        "view_angle": 60.0,
                        "samples": samples // 2,
                    }
                )
    elif kind == "curvature":
        # Spheres of radius R = k·ℓ in a uniform white world (and lit from behind the
        # camera): the energy against the view angle (across the image) and ℓ/R.
        for method in ("RANDOM_WALK", "RANDOM_WALK_SKIN"):
            for i, alb in enumerate(CURVATURE_ALBEDOS):
                ell_per_radius = mean_free_path([1, 1, 1], SCALE, alb, method)
                for k in CURVATURE_RADII:
                    sphere = 0.05
                    radius = (sphere / k / ell_per_radius).round(6).tolist()
                    c = {
                        "name": f"curv_{short[method]}_{i}_k{k:g}",
                        "geometry": "sphere",
                        "method": method,
                        "albedo": list(alb),
                        "radius": radius,
                        "scale": SCALE,
                        "sphere_radius": sphere,
                        "pixel": 2.2 * sphere / 64,
                        "width": 64,
                        "height": 64,
                        "samples": samples,
                        "sun_strength": 0.0,
                        "world_strength": 1.0,
                    }
                    # The same sphere lit by a sun behind the camera (fit.py's check).
                    front = {
                        **c,
                        "name": c["name"].replace("curv_", "front_"),
                        "sun_strength": math.pi,
                        "world_strength": 0.0,
                        "sun_dir": [0.0, -1.0, 0.0],
                    }
                    out += [c, front]
    elif kind == "holdout":
        # Albedos between the fit's nodes, another seed: the table's error where it
        # interpolates (the core's tests use these figures).
        for method in ("RANDOM_WALK", "RANDOM_WALK_SKIN"):
            c = case(
                f"holdout_{short[method]}", method, [0.12, 0.45, 0.88], target, samples, seed=7
            )
            out += [
                c,
                {
                    **c,
                    "name": c["name"].replace("holdout_", "holdoutuni_"),
                    "occluder": False,
                    "width": 32,
                    "height": 32,
                },
            ]
    elif kind == "spheres":
        out += sphere_cases(samples)
    elif kind == "uniform":
        # The fit's materials on a slab lit everywhere: the total reflectance.
        for c in grid("fit", samples, target):
            out.append(
                {
                    **c,
                    "name": c["name"].replace("fit_", "uniform_"),
                    "occluder": False,
                    "width": 32,
                    "height": 32,
                }
            )
    elif kind == "scale":
        for method in ("RANDOM_WALK", "RANDOM_WALK_SKIN", "BURLEY"):
            for px in (2.0, 8.0):
                out.append(
                    case(f"scale_{short[method]}_{px:g}px", method, [0.1, 0.5, 0.9], px, samples)
                )
    elif kind == "sensitivity":
        alb = [0.2, 0.5, 0.8]
        variants = {
            "RANDOM_WALK": [
                ("ior", 1.33),
                ("ior", 2.0),
                ("roughness", 0.0),
                ("roughness", 1.0),
                ("anisotropy", 0.5),
                ("anisotropy", 0.8),
            ],
            "RANDOM_WALK_SKIN": [
                ("subsurface_ior", 1.2),
                ("subsurface_ior", 1.6),
                ("anisotropy", 0.5),
                ("anisotropy", 0.8),
            ],
        }
        for method, items in variants.items():
            out.append(case(f"sens_{short[method]}_base", method, alb, target, samples))
            for key, value in items:
                out.append(
                    case(
                        f"sens_{short[method]}_{key}_{value:g}",
                        method,
                        alb,
                        target,
                        samples,
                        **{key: value},
                    )
                )
    elif kind == "thickness":
        # Whole slabs of the demo's marble under a sun straight down, from thin to deep:
        # what a walk loses through the far side when nothing below sends it back.
        ell = MARBLE["radius"][0] * MARBLE["scale"] / (4 * math.pi)
        for t in THICKNESSES:
            out.append(
                {"name": f"thickness_marble_{t}", "method": "RANDOM_WALK", **MARBLE,
                 "slab_depth": round(t * ell, 6), "slab_size": 2.0, "occluder": False,
                 "pixel": 0.01, "width": 32, "height": 16, "samples": samples}
            )  # fmt: skip
    else:
        raise SystemExit(f"unknown grid {kind!r}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "kind",
        choices=(
            "fit",
            "uniform",
            "view",
            "curvature",
            "holdout",
            "anisotropy",
            "scale",
            "sensitivity",
            "spheres",
            "thickness",
        ),
    )
    ap.add_argument("--samples", type=int, default=1024)
    ap.add_argument("--target", type=float, default=4.0, help="expected Burley d, pixels")
    args = ap.parse_args(argv)
    for c in grid(args.kind, args.samples, args.target):
        print(json.dumps(c))
    return 0


if __name__ == "__main__":
    sys.exit(main())
