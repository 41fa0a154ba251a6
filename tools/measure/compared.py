"""Posts scored against a ``cvsss compare`` folder (imported by the scripts beside it).

A compare folder (``cvsss compare BLEND --out COMPARE``) holds the ground truth
(``ground_truth/material``, ``ground_truth/off``) and the engine's frame without
subsurface (``renders/<engine>_<n>/off_####.exr``). The scripts here render the
same frames' passes, post them in some variants and score each finished frame
with ``core.eval.users_frame.frame_figures``: whole frame / subsurface pixels /
subsurface effect, dB.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from cvsss.core.eval.users_frame import frame_figures
from cvsss.core.io.exr import read_frame, read_result, read_rgb
from cvsss.sss_addon.blender.denoise_frame import EEVEE_DENOISE, FrameDenoiser


def arguments(doc: str, compare_help: str) -> argparse.ArgumentParser:
    """The arguments every script here takes, BLEND COMPARE OUT --frames A-B: the scene,
    its ``cvsss compare`` folder, the output folder and the compare's frames (the
    parser's description is the first line of ``doc``)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("blend", type=Path)
    parser.add_argument("compare", type=Path, help=compare_help)
    parser.add_argument("out", type=Path)
    parser.add_argument("--frames", required=True, help="A-B, as the compare's")
    return parser


def cvsss(*args: str) -> None:
    """Run the ``cvsss`` command line with this Python."""
    subprocess.run([sys.executable, "-m", "cvsss.sss_addon.cli.main", *args], check=True)


def render_passes(blend: Path, frames: str, out: Path, engine: str) -> Path:
    """Render ``frames`` ("A-B") of ``blend`` as passes with ``engine`` into ``out``;
    returns the passes folder."""
    cvsss(
        "render", str(blend), "--frames", frames, "--out", str(out), "--engine", engine,
        "--passes-only", "--no-ground-truth", "--no-reference", "--no-denoise", "--quiet",
    )  # fmt: skip
    return out / "passes"


def finished(post: Path, method: str, number: str) -> tuple[np.ndarray, SimpleNamespace]:
    """A posted frame as a finished RGBA frame (alpha 1), and of its result the (H, W)
    bool ``mask`` of subsurface pixels and the (H, W, 3) lighting ``sss`` (L)."""
    result = read_result(post / method / f"{number}.exr")
    mask = result["Mask"] > 0
    image = np.ones((*mask.shape, 4), np.float32)
    image[..., :3] = result["Composite"][..., :3]
    return image, SimpleNamespace(mask=mask, sss=result["SSS"][..., :3])


class Scorer:
    """Scores finished frames against a compare folder's ground truth (``prefix``:
    the engine's renders folder, ``eevee_`` or ``cycles_``)."""

    def __init__(self, compare: Path, prefix: str):
        self.compare = compare
        (self.renders,) = sorted((compare / "renders").glob(prefix + "*"))

    def __call__(self, image: np.ndarray, number: str) -> tuple[float, float, float]:
        """(whole, subsurface, effect) dB of frame ``number`` ("0021")."""
        truth = read_rgb(self.compare / "ground_truth" / "material" / f"{number}.exr")
        truth_off = read_rgb(self.compare / "ground_truth" / "off" / f"{number}.exr")
        off = read_rgb(self.renders / f"off_{number}.exr")
        f = frame_figures(image, truth, truth_off, off)
        return f.psnr_whole_db, f.psnr_subsurface_db, f.effect_db


def mean_row(rows: list[tuple[float, float, float]]) -> list[float]:
    """The mean over frames of (whole, subsurface, effect), to 0.01 dB."""
    return np.mean(rows, axis=0).round(2).tolist()


def scored_post(post: Path, method: str, passes: Path, score: Scorer, denoise: bool) -> list[float]:
    """The mean over ``passes``' frames of (whole, subsurface, effect) dB of ``method``'s
    finished frames in ``post``; with ``denoise`` they are denoised first as Apply on
    Render does on EEVEE (``EEVEE_DENOISE``: the post's lighting)."""
    rows = []
    with FrameDenoiser(EEVEE_DENOISE) as denoiser:
        for path in sorted(passes.glob("*.exr")):
            image, result = finished(post, method, path.stem)
            if denoise:
                image = denoiser.finished(image, result, read_frame(path), None)
            rows.append(score(image, path.stem))
    return mean_row(rows)
