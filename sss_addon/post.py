"""Post-process a directory of pass EXRs frame by frame (no Blender needed).

Layout written under ``out``::

    out/<method>/0001.exr   result layers (see core.exr.write_result)
    out/metrics.csv         frame,method,spp,pass_ms,psnr_db

History is carried from frame to frame per method, so frames are processed in
order. PSNR is luminance PSNR over SSS pixels of the composite against the
``reference`` method, display-referred (see core.metrics.psnr); it is empty
when no reference was computed.
"""

from __future__ import annotations

import csv
import io
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ..core.exr import OutputError, list_frames, read_frame, write_result
from ..core.metrics import psnr
from ..core.params import SSSParams
from ..core.pipeline import SequenceProcessor

METRICS_FIELDS = ("frame", "method", "spp", "pass_ms", "psnr_db")


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file and rename."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise OutputError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from exc


def format_metrics(rows: Sequence[dict]) -> str:
    """CSV text of metric rows (``METRICS_FIELDS`` columns)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=METRICS_FIELDS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: row.get(k, "") for k in METRICS_FIELDS})
    return buf.getvalue()


def _fmt(value: float | None, digits: int = 4) -> str:
    if value is None or value != value:  # None or NaN
        return ""
    return f"{value:.{digits}f}"


def post_process(
    passes: Path,
    out: Path,
    methods: Sequence[str],
    params: SSSParams,
    *,
    reference: bool = False,
    overwrite: bool = False,
    log: Callable[[str], None] | None = print,
) -> list[dict]:
    """Post-process every frame of ``passes`` with each method.

    Parameters
    ----------
    passes : directory of ``<digits>.exr`` pass files with JSON sidecars
    out : output directory
    methods : method names (core.methods)
    params : SSSParams
    reference : compute the reference (for PSNR) even if not in ``methods``
    overwrite : replace existing result files
    log : progress printer, or None

    Returns
    -------
    list of metric rows (dicts with METRICS_FIELDS keys).
    """
    frames = list_frames(passes)
    out = Path(out)
    names = list(dict.fromkeys(methods))
    need_ref = reference or "reference" in names
    if need_ref and "reference" not in names:
        names.append("reference")
    # Process the reference first each frame so PSNR is available at once.
    order = (["reference"] if need_ref else []) + [m for m in names if m != "reference"]
    for name in order:
        target = out / name
        if not overwrite:
            existing = [target / p.name for _, p in frames if (target / p.name).exists()]
            if existing:
                raise FileExistsError(
                    f"{existing[0]} already exists; pass --overwrite to replace "
                    f"{len(existing)} existing result(s)"
                )
    processors = {name: SequenceProcessor(name, params) for name in order}
    rows: list[dict] = []
    start = time.perf_counter()
    for i, (number, path) in enumerate(frames, 1):
        frame = read_frame(path, number=number)
        ref = None
        for name in order:
            result = processors[name].process(frame)
            if name == "reference":
                ref = result
            value = psnr(result.composite, ref.composite, result.mask, params.exposure) if ref else None
            write_result(out / name / path.name, result, overwrite=overwrite,
                         metadata={"source": path.name})
            rows.append({
                "frame": number, "method": name, "spp": _fmt(result.spp),
                "pass_ms": _fmt(result.pass_ms, 3), "psnr_db": _fmt(value, 3),
            })
            if log:
                elapsed = time.perf_counter() - start
                eta = elapsed / i * (len(frames) - i)
                log(f"frame {i}/{len(frames)} ({number}) {name:>9}: spp {result.spp:7.2f}  "
                    f"pass {result.pass_ms:8.2f} ms  psnr {_fmt(value, 2) or '-':>6} dB  "
                    f"[elapsed {elapsed:5.1f} s, eta {eta:5.1f} s]")
        write_text_atomic(out / "metrics.csv", format_metrics(rows))
    return rows
