"""``cvsss bench`` (``make bench``): the run, its memory measurement, files and plots.

The measuring functions are in :mod:`cvsss.core.bench` (what each figure
means is documented there). This front-end adds what core does not do:

- peak resident memory, one fresh subprocess per configuration
  (``python -m cvsss.sss_addon.cli.bench --rss-worker JSON``, VmHWM from
  ``/proc/self/status``, or ``ru_maxrss`` where there is no /proc);
- the machine it ran on (``environment``: CPU, load average, git revision);
- the numba kernel's compile time (``jit``): a fresh process compiles it into an
  empty cache directory, a second one loads it from there, and what they compiled
  is copied into this checkout's cache where that lacks it (compiled once a run);
- the files: ``OUT/bench.json``, ``OUT/quality_calibration.json`` (and the
  shipped ``core/data/quality_calibration.json`` with ``--write-calibration``),
  ``pareto.png``, ``pareto_backends.png``, ``quality.png`` and ``scaling.png``;
  progress and a summary of the targets and the ratios per backend on stdout.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import glob
import hashlib
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from ...core import bench
from ...core.backends import cache as numba_cache
from ...core.backends import select as mc_backend
from ...core.backends.compile import compile_all
from ...core.bench.config import MeasureRss
from ...core.eval import quality
from ...core.io.atomic import make_folder
from ...core.io.exr import list_frames
from ...core.methods import make_processor
from ...core.params import SSSParams
from ...core.synthetic import scene_frame
from ..farm.bench import measure_workers
from ..farm.cluster import FarmError
from .bench_plots import write_plots

#: The command that regenerates out/bench (recorded in bench.json).
REGENERATE = "cvsss bench --out out/bench"
#: Seconds one RSS subprocess may take.
RSS_TIMEOUT_S = 1800


# -- command line -----------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The flags of ``cvsss bench`` on ``parser``."""
    parser.add_argument("--out", type=Path, default=Path("out/bench"), help="output directory")
    parser.add_argument(
        "--passes",
        type=Path,
        default=None,
        help="pass directory for the Pareto sequence (default: synthetic flash)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="tiny sizes and few frames (seconds; a smoke run, not a measurement)",
    )
    parser.add_argument(
        "--sections",
        default=None,
        help=f"comma-separated subset of {','.join(bench.SECTIONS)}",
    )
    parser.add_argument(
        "--write-calibration",
        action="store_true",
        help="also replace the shipped core/data/quality_calibration.json",
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    parser.add_argument("--rss-worker", default=None, help=argparse.SUPPRESS)
    return parser


def add_parser(subparsers: Any) -> None:
    """Add the ``bench`` subcommand to ``subparsers`` (of ``cvsss``)."""
    add_arguments(
        subparsers.add_parser(
            "bench",
            help="speed and the speed/accuracy trade, measured (out/bench/bench.json + plots)",
            description="Speed and the speed/accuracy trade, measured.",
        )
    )


def config_from_args(args: argparse.Namespace) -> bench.BenchConfig:
    """The BenchConfig of ``--quick`` and ``--sections``.

    Raises
    ------
    ValueError
        ``--sections`` names an unknown section or none.
    """
    cfg = bench.QUICK if args.quick else bench.BenchConfig()
    if args.sections:
        names = tuple(s.strip() for s in args.sections.split(",") if s.strip())
        bad = [s for s in names if s not in bench.SECTIONS]
        if bad or not names:
            raise ValueError(
                f"--sections must be a subset of {','.join(bench.SECTIONS)}, "
                f"got {args.sections!r}"
            )
        cfg = dataclasses.replace(cfg, sections=names)
    return cfg


def run(args: argparse.Namespace) -> int:
    """Run ``cvsss bench`` from parsed arguments; returns the exit status.

    Raises
    ------
    ValueError
        Bad user input (an unknown section, a malformed ``--rss-worker`` spec).
    """
    if args.rss_worker:
        print(json.dumps(rss_worker(json.loads(args.rss_worker))))
        return 0
    run_bench(
        args.out,
        config_from_args(args),
        passes=args.passes,
        write_calibration=args.write_calibration,
        plots=not args.no_plots,
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m cvsss.sss_addon.cli.bench``: the same flags as ``cvsss bench``."""
    parser = add_arguments(
        argparse.ArgumentParser(
            prog="cvsss bench", description="Speed and the speed/accuracy trade, measured."
        )
    )
    args = parser.parse_args(None if argv is None else list(argv))
    try:
        return run(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


# -- memory ------------------------------------------------------------------------
def _proc_status(field_name: str) -> float | None:
    """A ``/proc/self/status`` field in MiB (Linux), else None."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(field_name + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _reset_peak() -> bool:
    """Reset VmHWM to the current RSS (Linux ≥ 4.0); False when unsupported."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _max_rss_mb() -> float:
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0


def rss_worker(spec: dict) -> dict:
    """Post-process frames of one configuration and report this process's memory.

    Run in a fresh subprocess per configuration (``python -m
    cvsss.sss_addon.cli.bench --rss-worker JSON``, ``spec`` one of
    :func:`cvsss.core.bench.rss_specs`) so configurations do not
    contaminate each other. Reports the peak over the whole process
    (interpreter, inputs, post-process) and, where Linux allows resetting the
    high-water mark, the peak while post-processing with the frame already in
    memory.
    """
    w, h = spec["size"]
    params = SSSParams(history_precision=spec["precision"], seed=spec.get("seed", 0))
    proc = make_processor(spec["method"], params)
    baseline = _proc_status("VmRSS")
    peak_input = 0.0
    post_peak = None
    input_mb = history_mb = 0.0
    for n in range(1, spec["frames"] + 1):
        frame = scene_frame(spec["scene"], n, w, h)
        passes = (frame.lighting, frame.albedo, frame.combined, frame.depth, frame.material)
        input_mb = sum(a.nbytes for a in passes) / 2**20
        del passes
        peak_input = max(peak_input, _proc_status("VmHWM") or 0.0)
        reset = _reset_peak()
        result = proc.process(frame)
        del result, frame
        if reset:
            post_peak = max(post_peak or 0.0, _proc_status("VmHWM") or 0.0)
    history = getattr(proc, "history", None)  # Monte Carlo methods only
    if history is not None:
        history_mb = history.nbytes() / 2**20
    peak = max(peak_input, post_peak or 0.0, 0.0)
    if peak == 0.0:
        peak = _max_rss_mb()
    return {
        "peak_rss_mb": peak,
        "backend": mc_backend.resolve(params.backend),
        "post_process_peak_mb": post_peak,
        "baseline_mb": baseline,
        "input_mb": input_mb,
        "history_mb": history_mb,
        "source": ("VmHWM" if baseline is not None else "ru_maxrss"),
    }


def _spawn_rss(spec: dict) -> dict:
    cmd = [sys.executable, "-m", f"{__package__}.bench", "--rss-worker", json.dumps(spec)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=RSS_TIMEOUT_S, check=False)
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def measure_rss(workers: int) -> MeasureRss:
    """Measures each spec in its own subprocess, ``workers`` at a time (results in order)."""

    def measure(specs: list[dict]) -> list[dict]:
        with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
            return list(pool.map(_spawn_rss, specs))

    return measure


# -- JIT compile time ------------------------------------------------------------------
#: A fresh process imports the backend, then compiles (or loads) its kernels; both timed.
_COMPILE_IN_FRESH_PROCESS = (
    "import json, time; t0 = time.perf_counter(); "
    "from cvsss.core.backends import compile, select; b = select.resolve('numba'); "
    "t1 = time.perf_counter(); s = compile.compile_all(PIXELS) if b == 'numba' else None; "
    "print(json.dumps({'import_s': t1 - t0, 'compile_s': s}))"
)


def measure_jit(pixels: int | None = None) -> dict:
    """Compile time of the numba kernel, separately from everything else.

    ``pixels``: compile only the sampling build frames of that many pixels take
    (:func:`core.backends.compile.compile_all`); None, every pass.

    Two fresh processes share an empty ``NUMBA_CACHE_DIR``: the first compiles
    the kernel and writes the cache (``compile_s``), the second loads it
    (``cache_load_s``); ``import_s`` is importing numba. What they compiled is
    then copied where this process's numba cache is missing it (:func:`adopt_compiled`,
    ``adopted``: files), so that the kernels are compiled once per run, not again
    here (on a clean clone that took another 53–61 s). ``{"skipped": …}`` where
    numba does not import.
    """
    ok, what = mc_backend.numba_status()
    if not ok:
        return {"skipped": what}
    out: dict[str, Any] = {"numba": what}
    with tempfile.TemporaryDirectory(prefix="cvsss-numba-") as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        for key in ("compile_s", "cache_load_s"):
            proc = subprocess.run(
                [sys.executable, "-c", _COMPILE_IN_FRESH_PROCESS.replace("PIXELS", repr(pixels))],
                capture_output=True,
                text=True,
                env=env,
                timeout=600,
                check=False,
            )
            if proc.returncode != 0:
                return {**out, "error": (proc.stderr.strip().splitlines() or ["failed"])[-1]}
            res = json.loads(proc.stdout.strip().splitlines()[-1])
            out[key] = res["compile_s"]
            out.setdefault("import_s", res["import_s"])
        out["adopted"] = adopt_compiled(Path(cache), numba_cache.SOURCES)
    return out


def numba_cache_folder(source: Path, cache_dir: Path) -> Path:
    """Where numba keeps the cache of the kernels of the modules in ``source`` (a folder)
    under a ``NUMBA_CACHE_DIR`` of ``cache_dir``: a subfolder named after the source
    folder and the SHA-1 of its path (numba's ``_CacheLocator.get_suitable_cache_subpath``)."""
    folder = os.path.abspath(source)
    digest = hashlib.sha1(folder.encode()).hexdigest()
    return cache_dir / f"{os.path.basename(folder)}_{digest}"


def _stale(index: Path, module: Path) -> bool:
    """Whether numba cannot use ``index`` for ``module``: it is missing, or was written
    before the module's source last changed (numba then finds its stamp out of date)."""
    try:
        written = index.stat().st_mtime_ns
    except FileNotFoundError:
        return True
    try:
        return written < module.stat().st_mtime_ns
    except FileNotFoundError:
        return False


def adopt_compiled(cache_dir: Path, source: Path, target: Path | None = None) -> int:
    """Copy the kernels compiled under the ``NUMBA_CACHE_DIR`` ``cache_dir`` to the
    cache this process reads, where that has no up-to-date index of them.

    Parameters
    ----------
    cache_dir : the ``NUMBA_CACHE_DIR`` another process compiled ``source``'s kernels into
    source : the folder of the modules whose kernels to copy
    target : the folder to copy them to; default where numba looks here: under this
        process's ``NUMBA_CACHE_DIR`` if set, else ``source/__pycache__``

    Returns
    -------
    int, files copied (0 where nothing was missing or ``target`` is not writable: then
    numba compiles again, as without this)

    A kernel's index (``.nbi``) records the source file's size and modification time,
    not the folder, so numba loads a copied entry exactly where it would load its own,
    and ignores it once the source changes. An index already there is replaced only
    when it is older than its module's source (written before the source last changed,
    so numba would not load it); each index is written last, after its kernels
    (``.nbc``), each file atomically, so an interrupted copy leaves no index without
    its kernels.
    """
    found = numba_cache_folder(source, cache_dir)
    if target is None:
        user = os.environ.get("NUMBA_CACHE_DIR")
        target = numba_cache_folder(source, Path(user)) if user else Path(source) / "__pycache__"
    if not found.is_dir():
        return 0
    copied = 0
    part = None
    try:
        target.mkdir(parents=True, exist_ok=True)
        for index in sorted(found.glob("*.nbi")):
            if not _stale(target / index.name, Path(source) / f"{index.name.split('.')[0]}.py"):
                continue
            stem = index.name[: -len(".nbi")]
            for path in [*sorted(found.glob(f"{glob.escape(stem)}.*.nbc")), index]:
                part = target / f".{path.name}.{os.getpid()}.tmp"
                shutil.copyfile(path, part)
                os.replace(part, target / path.name)
                part = None
                copied += 1
    except OSError:
        if part is not None:  # a copy that failed half-way leaves no temporary file
            with contextlib.suppress(OSError):
                part.unlink()
    return copied


# -- the whole run ------------------------------------------------------------------
def environment() -> dict:
    """The machine and code the bench ran on."""
    env = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "machine": platform.machine(),
        "system": platform.system(),
        "cpus": os.cpu_count(),
        "processor": platform.processor() or None,
        "load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            env["cpu_model"] = next(
                (ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), None
            )
    except OSError:
        pass
    root = Path(__file__).resolve().parents[2]

    def git(*argv: str) -> subprocess.CompletedProcess:
        return subprocess.run(
            ["git", "-C", str(root), *argv], capture_output=True, text=True, timeout=10, check=False
        )

    try:
        rev, dirty = git("rev-parse", "--short", "HEAD"), git("status", "--porcelain")
        if rev.returncode == 0:
            env["git"] = rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        pass
    return env


def run_bench(
    out: Path,
    config: bench.BenchConfig | None = None,
    *,
    passes: Path | None = None,
    write_calibration: bool = False,
    plots: bool = True,
    log: Callable[[str], None] | None = print,
) -> dict:
    """Run the bench, write ``out/bench.json``, the calibration and the plots.

    Parameters
    ----------
    out : output directory
    config : BenchConfig, default the full ``make bench`` configuration
    passes : pass directory to use for the Pareto sequence instead of the
        synthetic one (timing sections stay synthetic: they need sizes and
        coverages the directory does not have)
    write_calibration : also replace the shipped ``core/data/quality_calibration.json``
    plots : write the PNG figures (needs matplotlib)
    log : progress lines (default: printed), None for silence

    Returns
    -------
    dict, the content of bench.json (before NaN → null)
    """
    cfg = config or bench.BenchConfig()
    if passes is not None:
        list_frames(passes)  # a missing or empty folder is said now, not after the JIT
    out = Path(out)
    make_folder(out)
    start = time.perf_counter()
    result: dict[str, Any] = {
        "version": 1,
        "command": REGENERATE,
        "config": cfg.to_dict(),
        "environment": environment(),
        "jit": measure_jit(cfg.jit_pixels),
    }
    if log:
        log(f"[{time.perf_counter() - start:7.1f} s] jit: {result['jit']}")
    if mc_backend.numba_status()[0]:
        # Every kernel compiled (or loaded from this checkout's cache) before anything is
        # timed: a kernel's first use would otherwise compile it inside a timed frame (on a
        # clean clone the frames section's first as_ccv_t frame at 1280x720 read 8.1 s).
        t0 = time.perf_counter()
        compile_all()
        result["jit"]["in_process_s"] = time.perf_counter() - t0
        if log:
            log(f"[{time.perf_counter() - start:7.1f} s] kernels ready in this process")
    result.update(
        bench.run_sections(
            cfg,
            passes=passes,
            measure_rss=measure_rss(cfg.rss_workers),
            log=log,
            start=start,
            measure_workers=lambda c: _measure_workers(c, log, start),
        )
    )
    if "pareto" in result:
        cal = result["pareto"]["calibration"]
        bench.write_json(out / "quality_calibration.json", cal)
        if write_calibration:
            bench.write_json(quality.CALIBRATION_PATH, cal)
            quality._load_cached.cache_clear()
    result["wall_s"] = time.perf_counter() - start
    if hasattr(os, "getloadavg"):
        # Other processes on the machine slow some frames; interleaving spreads that over
        # every configuration, but the load is recorded so a noisy run can be recognised.
        result["environment"]["load_average_1min_end"] = os.getloadavg()[0]
    result["targets"] = bench.evaluate_targets(result)
    if plots:
        try:
            result["plots"] = [p.name for p in write_plots(result, out)]
        except ImportError as exc:
            result["plots"] = []
            if log:
                log(f"[{time.perf_counter() - start:7.1f} s] no plots: {exc}")
    bench.write_json(out / "bench.json", result)
    if log:
        log(format_summary(result))
        log(f"wrote {out / 'bench.json'} in {result['wall_s']:.0f} s")
    return result


def _measure_workers(cfg: bench.BenchConfig, log, start: float) -> dict:
    """The ``workers`` section (needs the cvsss[farm] extra; skipped without it: the
    cluster then raises FarmError)."""
    try:
        return measure_workers(
            cfg,
            None if log is None else lambda t: log(f"[{time.perf_counter() - start:7.1f} s] {t}"),
        )
    except FarmError as exc:
        return {"skipped": str(exc)}


def format_summary(result: dict) -> str:
    """The targets as a small text table, and the workers' speed-up."""
    lines = ["target                                  value        target     met"]
    for name, t in result.get("targets", {}).items():
        v = t["value"]
        vs = "n/a" if v is None else f"{v:.4g}"
        lines.append(f"{name:<38} {vs:>10}   {t['target']:>10}   {'yes' if t['met'] else 'NO'}")
    cpu = (result.get("environment") or {}).get("cpu_model") or "an unnamed CPU"
    for name, t in result.get("targets", {}).items():
        if name.startswith("ns_per_sample_vs_gather") and t.get("spread"):
            text = ", ".join(
                f"{size} {t['per_size'][size]:.2f}x ({lo:.2f}–{hi:.2f})"
                for size, (lo, hi) in t["spread"].items()
            )
            lines.append(f"{name}: median of {t['runs']} interleaved runs {text} on {cpu}")
    ns, gather = result.get("ns_per_sample", {}), result.get("gather_ns_per_sample", {})
    for b, sizes in ns.items():
        for size, v in sizes.items():
            g = gather.get(b, {}).get(size)
            ratio = v / g if v and g else float("nan")
            default = " (default)" if b == result.get("backend_default") else ""
            lines.append(
                f"{b}{default} {size}: {v:.1f} ns/sample, gather roofline {g:.2f} ns: {ratio:.1f}x"
            )
    frames = result.get("frame_time_ms") or {}
    for b in result.get("cost", {}).get("backends", []):
        for size, rows in frames.get(b, {}).items():
            text = ", ".join(f"{m} {ms:.0f}" for m, ms in rows.items())
            lines.append(f"frame ms {b} {size}: {text}")
    steady = frames.get("steady") or {}
    for m, row in steady.get("methods", {}).items():
        lines.append(
            f"steady frame s {steady['backend']} {steady['size']} {m}: {row['median_s']:.3f} "
            f"(min {row['min_s']:.3f}, max {row['max_s']:.3f}, {len(row['runs_s'])} frames)"
        )
    jit = result.get("jit") or {}
    if "compile_s" in jit:
        lines.append(
            f"numba JIT: compile {jit['compile_s']:.1f} s, load from cache {jit['cache_load_s']:.2f} s"
            + (f", {jit['adopted']} cache files reused here" if jit.get("adopted") else "")
        )
    w = result.get("workers") or {}
    if "speedup_2_vs_1" in w:
        lines.append(
            f"tiled post at {w['size']}: 2 workers {w['speedup_2_vs_1']:.2f}x faster than 1 "
            f"({w['runs']['1']['wall_s']:.1f} s -> {w['runs']['2']['wall_s']:.1f} s on "
            f"{w['cpus']} cores), output {'identical' if w['identical'] else 'DIFFERENT'} "
            f"to cvsss post; from CPU times, on dedicated cores: {w['cpu_speedup_2_vs_1']:.2f}x"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
