"""The bench's ``workers`` section: the tiled post on 1 and 2 Dask workers, measured.

Writes the synthetic sequence's passes at ``workers_size`` to a temporary
folder, runs ``cvsss post`` on them without workers, then with each count of
``workers_counts`` on a local cluster (started before the clock starts;
``repeats`` alternating rounds, the best kept), and checks that every output
equals the run without workers bit for bit. On a machine other jobs share,
wall times mostly measure the sharing; CPU times do not, so the section also
estimates the wall time on dedicated cores: the busiest worker's tile CPU
time plus the client's CPU time (``cpu_estimate_s``). Besides
the wall times and the speed-up it records what the README's throughput model
needs: the work per tile (summed process() time of a tile's window on its
worker), the halo overhead (window pixels over image pixels − 1), the bytes
moved per tile and frame, and the client's time outside waiting.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from ...core.bench import BenchConfig, size_key
from ...core.eval.compare import output_differences
from ...core.io.exr import write_passes
from ...core.params import SSSParams
from ...core.run import RunSpec, run_folder
from ...core.synthetic import scene_frame
from ...core.tiling import tile_cores
from .cluster import open_cluster
from .post import tiled_processors


def measure_workers(cfg: BenchConfig, log: Callable[[str], None] | None = None) -> dict:
    """The ``workers`` section of the bench (see the module doc)."""
    width, height = cfg.workers_size
    spec = RunSpec(tuple(cfg.workers_methods), SSSParams(seed=cfg.seed))
    out: dict = {
        "size": size_key(cfg.workers_size),
        "frames": cfg.workers_frames,
        "methods": list(cfg.workers_methods),
        "tile": cfg.workers_tile,
        "tiles_per_frame": len(tile_cores((height, width), cfg.workers_tile)),
        "cpus": os.cpu_count(),
        "load_average_1min_start": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
        "runs": {},
    }
    with tempfile.TemporaryDirectory(prefix="cvsss-bench-workers-") as tmp:
        tmp = Path(tmp)
        for n in range(1, cfg.workers_frames + 1):
            write_passes(tmp / "passes" / f"{n:04d}.exr", scene_frame(cfg.scene, n, width, height))
        stats: dict[int, tuple[dict, dict]] = {}
        t0 = time.perf_counter()
        run_folder(tmp / "passes", tmp / "plain", spec)
        out["plain_s"] = time.perf_counter() - t0
        if log:
            log(f"workers: cvsss post without workers {out['plain_s']:.1f} s")
        identical = True
        # Configurations alternate, `repeats` rounds, best wall time kept: the machine
        # may be shared, and interleaving spreads other loads over every configuration.
        walls: dict[int, list[float]] = {c: [] for c in cfg.workers_counts}
        estimates: dict[int, list[float]] = {c: [] for c in cfg.workers_counts}
        for _round in range(max(cfg.repeats, 1)):
            for count in cfg.workers_counts:
                folder = tmp / f"w{count}"
                with open_cluster(count) as executor:
                    make = tiled_processors(executor, cfg.workers_tile)
                    t0, c0 = time.perf_counter(), time.process_time()
                    run_folder(
                        tmp / "passes",
                        folder,
                        spec,
                        processors=make,
                        existing="overwrite",
                        lookahead=True,
                    )
                    wall = time.perf_counter() - t0
                    client_cpu = time.process_time() - c0
                walls[count].append(wall)
                (session,) = make.sessions.values()
                # CPU time does not depend on what else the machine runs: the busiest
                # worker's tile CPU plus the client's (it reads, assembles and writes
                # between frames) estimates the wall time on dedicated cores.
                busiest = max(session.worker_cpu.values(), default=0.0)
                estimates[count].append(busiest + client_cpu)
                if walls[count][-1] == min(walls[count]):
                    stats[count] = (
                        dict(session.stats),
                        dict(session.halos),
                        {"client_cpu_s": client_cpu, "busiest_worker_cpu_s": busiest},
                    )
                diffs = output_differences(tmp / "plain", folder)
                identical &= not diffs
                if log:
                    log(
                        f"workers: {count} worker(s) {wall:.1f} s, "
                        f"{'identical' if not diffs else 'DIFFERENT: ' + '; '.join(diffs[:3])}"
                    )
        for count in cfg.workers_counts:
            st, halos, cpu = stats[count]
            tiles = st["tiles"]
            out["runs"][str(count)] = {
                "wall_s": min(walls[count]),
                "wall_s_all": walls[count],
                "cpu_estimate_s": min(estimates[count]),
                **cpu,
                "tile_cpu_s": st["cpu_s"],
                "cpu_ms_per_tile": 1e3 * st["cpu_s"] / tiles if tiles else None,
                "work_s": st["work_s"],
                "client_s": st["client_s"],
                "halo_px_mean": sum(halos.values()) / max(len(halos), 1),
                "work_ms_per_tile": 1e3 * st["work_s"] / tiles if tiles else None,
                "halo_overhead": st["window_px"] / st["image_px"] - 1.0 if st["image_px"] else None,
                # Passes of a window are sent once per frame for every method.
                "passes_bytes_per_tile": st["bytes_passes"]
                / max(st["frames"], 1)
                / out["tiles_per_frame"],
                "output_bytes_per_tile": st["bytes_out"] / tiles if tiles else None,
            }
    runs = out["runs"]
    out["identical"] = identical
    if "1" in runs and "2" in runs:
        out["speedup_2_vs_1"] = runs["1"]["wall_s"] / runs["2"]["wall_s"]
        out["cpu_speedup_2_vs_1"] = runs["1"]["cpu_estimate_s"] / runs["2"]["cpu_estimate_s"]
    if "2" in runs:
        out["speedup_2_vs_plain"] = out["plain_s"] / runs["2"]["wall_s"]
    out["load_average_1min_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else None
    return out
