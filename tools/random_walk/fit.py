"""Fit Burley shapes and energy factors to Cycles' random-walk renders; write the model's data.

Reads the renders of render_slabs.py (cases from cases.py) in one folder:

``fit_*``
    shadow edges on the slab at the default material settings, and at other
    Subsurface Anisotropy values (one table per anisotropy): per channel a
    least-squares fit of a Burley edge response (edge.py) gives the shape d,
    hence ``f = d/ℓ`` with ℓ the walk's mean free path
    (cvsss.core.profiles.random_walk.mean_free_path);
``uniform_*``, ``view*_*``
    the same materials lit everywhere: the total reflectance over Cycles'
    subsurface albedo (Diffuse Color pass), the energy factor ``e``; seen along
    the normal, and from other view angles (the walk's entry refracts the view
    ray, so e depends on the view angle; Burley's does not);
``curv_*``, ``front_*``
    spheres of radius R = k·ℓ in a uniform white world (the curvature
    factor's table) and lit from behind the camera (a check): their
    reflectance over the flat model's, against ``ℓ/R``;
``scale_*``, ``sens_*``, ``holdout_*`` and ``fit_burley_*``
    checks: f at 2 and 8 pixels per d, f and e under other IOR, Roughness,
    Subsurface IOR and Anisotropy, between the nodes (albedo and anisotropy),
    and Cycles' own Christensen-Burley through
    the same pipeline (it must give f = e = 1).

and writes the tables with the errors of the fit. The shipped data file was
made with::

    C=tools/random_walk/cases.py
    { python $C fit; python $C uniform; python $C holdout; python $C view
      python $C scale --samples 256; python $C sensitivity --samples 256
      python $C anisotropy --samples 256; python $C curvature --samples 512
    } > cases.jsonl
    nice -n 10 python tools/random_walk/render_slabs.py cases.jsonl renders   # hours on 2 cores
    python tools/random_walk/fit.py renders --out core/data/random_walk_fit.json

(with the project importable as ``cvsss``; Blender 5.0.1's bpy module).

Errors stated (all per channel)
-------------------------------
``edge_rms``, ``edge_max``
    residual of the fitted Burley edge response against the rendered one,
    relative to the lit side's level: how well one Burley d represents the
    walk's profile (includes the renders' noise, ``edge_noise``: the mean
    standard error of the column means, same units).
``edge_psnr_fit``, ``edge_psnr_burley``
    PSNR (peak = the lit level, the edge image's own scale) of the fitted
    Burley edge, and of the plain Burley one (d = ℓ, e = 1, what the
    post-process used before), against the rendered edge.
``holdout``
    f and e measured at albedos and anisotropies between the nodes (another
    seed), and the model's relative error there.
``leave_one_out``
    relative error of f and e at each inner albedo node when it is predicted by
    interpolating its neighbours: the table's error between nodes.
``scale``
    f measured at other d (pixels per d) against the table.
``curvature_by_view``
    the curvature factor of each sphere over bands of the view cosine (the
    model uses their mean), front-lit and uniformly lit.
``curvature_front_light``
    the same ratio for spheres lit from behind the camera: it also holds the
    light the profile spreads from the bright centre to the dim limb and the
    unseen back, so it is lower than the uniform one where ℓ/R and the albedo
    are large.
``oblique_view_edge``
    f of shadow edges seen 60 degrees off the normal (the edge runs across
    the tilt) against the normal-view table: the model keeps the normal
    view's d at every view angle.
``sensitivity``
    relative change of f and e when one material input leaves its default.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import edge

from cvsss.core.profiles.random_walk import (
    FIT_FORMAT,
    lookup,
    mean_free_path,
    shape,
    view_factor,
)

METHODS = ("RANDOM_WALK", "RANDOM_WALK_SKIN")
DEFAULT_INPUTS = {"ior": 1.5, "roughness": 0.5, "subsurface_ior": 1.4, "anisotropy": 0.0}


def _ell(case: dict) -> np.ndarray:
    return mean_free_path(
        case["radius"],
        case["scale"],
        case["albedo"],
        case["method"],
        case.get("subsurface_ior", 1.4),
    )


def _psnr(a: np.ndarray, b: np.ndarray, peak: float) -> float:
    mse = float(np.mean((np.asarray(a) - np.asarray(b)) ** 2))
    return 10.0 * math.log10(peak**2 / mse) if mse > 0 else math.inf


def edge_fits(path: Path) -> list[dict]:
    """Per channel of one edge render: albedo, f, fit errors and the plain-Burley error."""
    p = edge.column_profile(path)
    case = p["case"]
    ell = _ell(case)
    out = []
    for ch in range(3):
        y = p["y"][:, ch]
        fit = edge.fit_channel(p["x"], y, p["width"], ell[ch])
        k = fit["K"]
        model = k * edge.pixel_edge(p["x"], p["width"], fit["d"])
        plain = p["albedo_pass"][ch] * edge.pixel_edge(p["x"], p["width"], ell[ch])
        out.append(
            {
                "albedo": case["albedo"][ch],
                "f": fit["d"] / ell[ch],
                "d_px": fit["d"] / case["pixel"],
                "edge_level": k / p["albedo_pass"][ch],
                "edge_rms": fit["rms"],
                "edge_max": fit["max_abs"],
                "edge_noise": float(np.mean(p["sem"][:, ch]) / k),
                "edge_psnr_fit": _psnr(model, y, k),
                "edge_psnr_burley": _psnr(plain, y, k),
                "case": case,
            }
        )
    return out


def energy(path: Path) -> np.ndarray:
    """(3,) total reflectance over the Diffuse Color pass of a uniformly lit render."""
    passes = edge.read_exr(path)
    lit = passes["Combined"][..., :3].reshape(-1, 3).mean(axis=0)
    return lit / passes["Diffuse Color"][..., :3].reshape(-1, 3).mean(axis=0)


def _nodes(rows: list[dict], energies: dict[float, float]) -> dict:
    rows = sorted(rows, key=lambda r: r["albedo"])
    a = np.array([r["albedo"] for r in rows])
    keep = np.concatenate([[True], np.diff(a) > 0])  # a repeated albedo pads the last triple
    rows = [r for r, k in zip(rows, keep, strict=True) if k]
    a = np.array([r["albedo"] for r in rows])
    # A brighter medium scatters at least as far; above A = 0.9 the measured f is flat
    # (Cycles ends walks after 256 bounces) and its noise could make it dip.
    f = np.maximum.accumulate([r["f"] for r in rows])
    return {
        "albedo": a.tolist(),
        "d_scale": [round(float(v), 5) for v in f],
        "energy": [round(energies[r["albedo"]], 5) for r in rows],
        "edge_rms": [round(r["edge_rms"], 5) for r in rows],
        "edge_max": [round(r["edge_max"], 5) for r in rows],
        "edge_noise": [round(r["edge_noise"], 5) for r in rows],
        "edge_psnr_fit": [round(r["edge_psnr_fit"], 2) for r in rows],
        "edge_psnr_burley": [round(r["edge_psnr_burley"], 2) for r in rows],
    }


def _leave_one_out(table: dict) -> dict:
    a = np.array(table["albedo"])
    out = {"anisotropy": table["anisotropy"]}
    for key, name in (("d_scale", "f"), ("energy", "e")):
        v = np.array(table[key])
        err = [
            abs(np.interp(a[i], a[[i - 1, i + 1]], v[[i - 1, i + 1]]) / v[i] - 1)
            for i in range(1, len(a) - 1)
        ]
        out[f"{name}_max"] = round(float(np.max(err)), 4)
        out[f"{name}_mean"] = round(float(np.mean(err)), 4)
    return out


def _model_at(methods: dict, method: str, albedo: float, anisotropy: float) -> tuple:
    """(f, e) of the tables being written, through the core's own lookup."""
    tables = [
        (t["anisotropy"], np.array(t["albedo"]), np.array(t["d_scale"]), np.array(t["energy"]))
        for t in methods[method]["tables"]
    ]
    f, e = lookup(tables, np.full(3, albedo), anisotropy)
    return float(f[0]), float(e[0])


def _view_energy(folder: Path, method: str) -> dict:
    """The energy factor against the view angle (anisotropy 0): uniformly lit slabs seen
    from ``view_angle`` degrees, over albedo nodes; cos_view = 1 is the fit's own."""
    by_angle: dict = {0.0: {}}
    for path in sorted(folder.glob("uniform_*.exr")):
        case = json.loads(path.with_suffix(".json").read_text())
        if case["method"] != method or case.get("anisotropy", 0.0) != 0.0:
            continue
        for ch, e in enumerate(energy(path)):
            by_angle[0.0][case["albedo"][ch]] = float(e)
    for path in sorted(folder.glob("view*_*.exr")):
        case = json.loads(path.with_suffix(".json").read_text())
        if case["method"] != method or case.get("anisotropy", 0.0) != 0.0:
            continue
        row = by_angle.setdefault(case["view_angle"], {})
        for ch, e in enumerate(energy(path)):
            row[case["albedo"][ch]] = float(e)
    albedo = sorted(by_angle[0.0])
    angles = sorted(a for a, row in by_angle.items() if sorted(row) == albedo)
    return {
        "view_angle": angles,
        "cos_view": [round(math.cos(math.radians(a)), 6) for a in angles],
        "albedo": albedo,
        "energy": [[round(by_angle[a][v], 5) for v in albedo] for a in angles],
    }


def _curvature(folder: Path, method: str, base: Path, prefix: str) -> tuple[dict, list]:
    """The reflectance of spheres over the flat model's, against ℓ/R.

    ``prefix`` "curv": spheres in a uniform white world, averaged over the disc
    out to 75 degrees; "front": lit by a sun behind the camera (irradiance
    cos θ), averaged out to 60 degrees. ``base`` holds the flat tables (energy,
    view factor) already fitted: each sphere pixel's reflectance is divided by
    the flat model at its albedo and view angle.
    """
    rows: dict = {}
    spread = []
    front = prefix == "front"
    for path in sorted(folder.glob(f"{prefix}_*.exr")):
        case = json.loads(path.with_suffix(".json").read_text())
        if case["method"] != method:
            continue
        passes = edge.read_exr(path)
        e = (passes["Diffuse Direct"] + passes["Diffuse Indirect"])[..., :3].astype(np.float64)
        h, w = e.shape[:2]
        yy, xx = np.mgrid[0:h, 0:w]
        rho = np.hypot(xx - w / 2 + 0.5, yy - h / 2 + 0.5) * case["pixel"]
        rho /= case["sphere_radius"]
        mu = np.sqrt(np.clip(1 - rho**2, 0, 1))
        disc = mu >= math.cos(math.radians(60 if front else 75))
        ell = _ell(case)
        _, flat_e = shape(case["radius"], case["scale"], case["albedo"], method, path=base)
        flat = flat_e * view_factor(case["albedo"], mu[disc], method, path=base)
        if front:  # a Lambertian surface would show cos θ
            flat *= mu[disc][:, None]
        ratio = e[disc] / flat
        for ch in range(3):
            x = round(float(ell[ch] / case["sphere_radius"]), 4)
            rows.setdefault(x, {})[case["albedo"][ch]] = float(ratio[:, ch].mean())
            # How much the factor varies across the disc (the model averages it).
            bands = ((0.26, 0.5), (0.5, 0.7), (0.7, 0.9), (0.9, 1.01))
            bins = [
                ratio[(mu[disc] >= lo) & (mu[disc] < hi), ch].mean()
                for lo, hi in bands[1 if front else 0 :]
            ]
            spread.append(
                {
                    "method": method,
                    "lighting": "uniform" if prefix == "curv" else "front",
                    "albedo": case["albedo"][ch],
                    "ell_curvature": x,
                    "factor": round(float(ratio[:, ch].mean()), 4),
                    "factor_by_view": [round(float(b), 4) for b in bins],
                }
            )
    if not rows:
        return None, spread
    albedo = sorted(next(iter(rows.values())))
    xs = sorted(x for x, row in rows.items() if sorted(row) == albedo)
    return {
        "ell_curvature": [0.0, *xs],
        "albedo": albedo,
        "factor": [[1.0] * len(albedo)] + [[round(rows[x][a], 5) for a in albedo] for x in xs],
    }, spread


def build(folder: Path) -> dict:
    groups: dict = {}  # (method, anisotropy) -> (rows, energies)
    for path in sorted(folder.glob("fit_*.exr")):
        case = json.loads(path.with_suffix(".json").read_text())
        if case["method"] not in METHODS:
            continue
        rows, energies = groups.setdefault((case["method"], case.get("anisotropy", 0.0)), ([], {}))
        got = edge_fits(path)
        rows += got
        e = energy(folder / path.name.replace("fit_", "uniform_", 1))
        for ch, r in enumerate(got):
            energies[r["albedo"]] = float(e[ch])
    methods = {}
    for method in METHODS:
        keys = sorted(g for m, g in groups if m == method)
        if 0.0 not in keys:
            raise SystemExit(f"no fit renders of {method} at anisotropy 0 in {folder}")
        methods[method] = {
            "tables": [
                {
                    "anisotropy": g,
                    "samples": groups[(method, g)][0][0]["case"]["samples"],
                    **_nodes(*groups[(method, g)]),
                }
                for g in keys
            ],
            "view": _view_energy(folder, method),
        }
    cases = {m: groups[(m, 0.0)][0][0]["case"] for m in METHODS}

    # The curvature factor divides by the flat model: write that first, then add it.
    errors_extra: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "flat.json"
        base.write_text(json.dumps({"format": FIT_FORMAT, "methods": methods}))
        curvature_spread = []
        for method in METHODS:
            # The table is the uniformly lit one: with the lighting the same everywhere
            # the post-process returns it unchanged, so the sphere's ratio to the flat
            # model is what the energy lacks. Lit from behind the camera the ratio also
            # holds the light the profile carries into the dim limb and the unseen
            # back (the post's own business): kept as a check.
            table, spread = _curvature(folder, method, base, "curv")
            front, spread_f = _curvature(folder, method, base, "front")
            curvature_spread += spread + spread_f
            if table is not None:
                methods[method]["curvature"] = table
            if front is not None:
                errors_extra.setdefault("curvature_front_light", {})[method] = front

    errors: dict = {
        "leave_one_out": {
            m: [_leave_one_out(t) for t in t_all["tables"]] for m, t_all in methods.items()
        }
    }

    control = []
    for path in sorted(folder.glob("fit_burley_*.exr")):
        e = energy(folder / path.name.replace("fit_", "uniform_"))
        for ch, r in enumerate(edge_fits(path)):
            control.append(
                {
                    "albedo": r["albedo"],
                    "f": round(r["f"], 4),
                    "e": round(float(e[ch]), 4),
                    "edge_rms": round(r["edge_rms"], 4),
                }
            )
    errors["burley_control"] = control

    holdout = []
    for path in sorted(folder.glob("holdout_*.exr")):
        e = energy(folder / path.name.replace("holdout_", "holdoutuni_"))
        for ch, r in enumerate(edge_fits(path)):
            m, g = r["case"]["method"], r["case"].get("anisotropy", 0.0)
            f_t, e_t = _model_at(methods, m, r["albedo"], g)
            holdout.append(
                {
                    "method": m,
                    "anisotropy": g,
                    "albedo": r["albedo"],
                    "f": round(r["f"], 4),
                    "e": round(float(e[ch]), 4),
                    "f_rel_err": round(f_t / r["f"] - 1, 4),
                    "e_rel_err": round(e_t / float(e[ch]) - 1, 4),
                    "edge_rms": round(r["edge_rms"], 4),
                }
            )
    errors["holdout"] = holdout

    scale = []
    for path in sorted(folder.glob("scale_*.exr")):
        for r in edge_fits(path):
            m = r["case"]["method"]
            want = _model_at(methods, m, r["albedo"], 0.0)[0] if m in methods else 1.0
            scale.append(
                {
                    "method": m,
                    "albedo": r["albedo"],
                    "d_px": round(r["d_px"], 2),
                    "f": round(r["f"], 4),
                    "f_rel_err": round(r["f"] / want - 1, 4),
                }
            )
    errors["scale"] = scale

    oblique = []
    for path in sorted(folder.glob("edge*_*.exr")):
        for r in edge_fits(path):
            m = r["case"]["method"]
            want = _model_at(methods, m, r["albedo"], 0.0)[0] if m in methods else 1.0
            oblique.append(
                {
                    "method": m,
                    "view_angle": r["case"]["view_angle"],
                    "albedo": r["albedo"],
                    "f": round(r["f"], 4),
                    "f_rel_to_normal_view": round(r["f"] / want - 1, 4),
                    "edge_rms": round(r["edge_rms"], 4),
                    "edge_max": round(r["edge_max"], 4),
                }
            )
    errors["oblique_view_edge"] = oblique
    errors["curvature_by_view"] = curvature_spread
    errors.update(errors_extra)

    sens = []
    base = {}
    for path in sorted(folder.glob("sens_*_base.exr")):
        for r in edge_fits(path):
            base[(r["case"]["method"], r["albedo"])] = r
    for path in sorted(folder.glob("sens_*.exr")):
        if path.stem.endswith("_base"):
            continue
        for r in edge_fits(path):
            c = r["case"]
            b = base[(c["method"], r["albedo"])]
            changed = {k: c[k] for k, v in DEFAULT_INPUTS.items() if c.get(k, v) != v}
            sens.append(
                {
                    "method": c["method"],
                    **changed,
                    "albedo": r["albedo"],
                    "f_rel": round(r["f"] / b["f"] - 1, 4),
                    "edge_level_rel": round(r["edge_level"] / b["edge_level"] - 1, 4),
                }
            )
    errors["sensitivity"] = sens

    some = next(iter(cases.values()))
    return {
        "format": FIT_FORMAT,
        "command": "python tools/random_walk/fit.py RENDERS --out core/data/random_walk_fit.json",
        "blender": some.get("blender"),
        "setup": {
            "geometry": "semi-infinite slab, shadow edge of a sun at normal incidence, "
            "orthographic view along the normal",
            "inputs": DEFAULT_INPUTS,
            "pixels": [some["width"], some["height"]],
            "truncate": 16.0,
            "d_scale": "Burley d over the walk's mean free path l (least-squares edge fit)",
            "energy": "total reflectance of the lit slab over the Diffuse Color pass",
        },
        "methods": methods,
        "errors": errors,
    }


def _compact(text: str) -> str:
    """Lists of numbers (and of such lists), and short records, on one line: the file stays
    small and readable."""
    number = r"-?[0-9.eE+-]+|null|true|false"
    flat = re.compile(r"\[\s*((?:" + number + r")(?:,\s*(?:" + number + r"))*)\s*\]")
    text = flat.sub(lambda m: "[" + ", ".join(v.strip() for v in m.group(1).split(",")) + "]", text)
    nested = re.compile(r"\[\s*((?:\[[^\[\]]*\])(?:,\s*\[[^\[\]]*\])*)\s*\]")
    text = nested.sub(lambda m: "[" + re.sub(r"\],\s*\[", "], [", m.group(1)) + "]", text)

    def one_line(m):
        line = re.sub(r"\s*\n\s*", " ", m.group(0)).replace("{ ", "{").replace(" }", "}")
        return line if len(line) <= 160 else m.group(0)

    return re.sub(r"\{[^{}]*\}", one_line, text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("renders", type=Path)
    ap.add_argument("--out", type=Path, help="write the JSON here (default: stdout)")
    args = ap.parse_args(argv)
    data = build(args.renders)
    text = _compact(json.dumps(data, indent=1)) + "\n"
    if args.out:
        args.out.write_text(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
