"""Where the compiled kernel's time goes, from Linux ``perf`` samples mapped to source lines.

Runs itself under ``perf record -e cpu-clock`` (a timer event: it works in
virtual machines without hardware counters) with ``NUMBA_DEBUGINFO=1`` and a
fresh numba cache, so that the kernel is compiled in the run with line
information. The child runs the serial build of the kernel
(``core.mc.estimator_numba.pixel_sums_serial``: one thread, the same code as
the parallel one) on the steady flash frame of ``shared.steady`` with every
SSS pixel at ``--counts`` samples (the frame's own ``as_ccv`` counts without
it), ``--calls`` times, and writes the kernel's machine code and assembly.
The parent maps each sample's instruction address to the assembly's
instruction at that place (padding nops skipped) and so to the source
line of its ``.loc`` directive, and prints the share of the kernel's samples
per stage of ``pixel_sums`` (found by the comments that open them), per source
line and per instruction.

A timer sample names the instruction waiting to retire: a slow load shows on
the instruction after it. Instructions the compiler gives no line (loop set-up,
spills) are counted apart, by the lines around them. Needs ``perf`` on the
PATH and ``kernel.perf_event_paranoid`` ≤ 2. Run from the repo root:

    .venv/bin/python docs/checks/kernel_profile.py [WxH] [--counts N] [--calls N] [--top K]
"""

import argparse
import bisect
import collections
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SOURCE = Path(__file__).resolve().parents[2] / "core" / "backends" / "numba" / "sampling.py"
#: Stages of pixel_sums, each opened by the first source line that contains its marker
#: (in this order); a stage runs to the next one's first line.
MARKERS = (
    ("buffers", "fb = np.zeros(_ROWS * BATCH"),
    ("pre-pass", "for k in range(first, last):"),
    ("pixel set-up", "for k in range(first, last):"),
    ("batch start", "for k0 in range(1, m + 1, BATCH):"),
    ("1a R2, channel", "# Stage 1a"),
    ("1b tables, position", "# Stage 1b"),
    ("2a landing texel", "# Stage 2a"),
    ("2b surface tests", "# Stage 2b"),
    ("3 weights (vector)", "# Stage 3"),
    ("3 table weights", "                for j in range(nb):"),
    ("4 gather, sums", "# Stage 4"),
    ("pixel end", "mf = np.float64(m)"),
    ("after", "return var, fallback"),
)
#: Inlined helpers and the stage they belong to.
HELPERS = {"def _pcg3d_xy": "pre-pass", "def _pdf": "3 table weights"}


def stage_lines(lines: list[str]) -> list[tuple[int, str]]:
    """(first line, stage) in source order, from MARKERS; ``lines`` the kernel's source."""
    start = next(i for i, s in enumerate(lines) if s.startswith("def _pixel_sums("))
    out, at = [], start
    for name, marker in MARKERS:
        at = next(i for i in range(at + 1, len(lines)) if marker in lines[i])
        out.append((at + 1, name))
    return out


def helper_ranges(lines: list[str]) -> list[tuple[int, int, str]]:
    """(first, last line, stage) of each helper of HELPERS; ``lines`` the kernel's source."""
    out = []
    for head, stage in HELPERS.items():
        a = next(i for i, s in enumerate(lines) if s.startswith(head + "("))
        b = next(i for i in range(a + 1, len(lines)) if lines[i].startswith(("def ", "@")))
        out.append((a + 1, b, stage))
    return out


def child(folder: Path, size: tuple[int, int], counts: int | None, calls: int) -> None:
    """Run the serial kernel ``calls`` times; write its code, assembly and address."""
    import numpy as np
    from shared import steady_geometry

    from cvsss.core.backends.numba import sampling as en
    from cvsss.core.mc.estimator import _distant_sums_compiled, mirror_slots
    from cvsss.core.params import SSSParams

    params = SSSParams(backend="numba")
    frame, profile, geom, n = steady_geometry(size, params)
    if counts is not None:
        n = np.full(geom.size, counts, np.int64)
    active = np.flatnonzero((n > 0) & (geom.gamma_sum > 0))
    en.build_for = lambda samples, pixels=0: en.pixel_sums_serial

    def run():
        _distant_sums_compiled(
            geom, profile, n, active, frame.lighting, frame.depth, frame=frame.number,
            seed=params.seed, depth_slope=params.depth_slope, variance=True, disk=True,
            hidden_light=params.hidden_light, contact=params.contact,
            hidden_mirror=mirror_slots(profile, params.hidden_mirror), chunk_samples=1 << 16,
            distant=np.empty((geom.size, 3)), start=active.size == geom.size,
            samples=int(n[active].sum()),
        )  # fmt: skip

    run()  # compiles
    sig = en.pixel_sums_serial.signatures[0]
    overload = en.pixel_sums_serial.overloads[sig]
    name = overload.fndesc.llvm_func_name
    addr = overload.library.get_pointer_to_function(name)
    (folder / "asm.s").write_text(overload.library.get_asm_str())
    for line in Path("/proc/self/maps").read_text().splitlines():
        lo, hi = (int(v, 16) for v in line.split()[0].split("-"))
        if lo <= addr < hi:
            with open("/proc/self/mem", "rb") as mem:
                mem.seek(addr)
                (folder / "code.bin").write_bytes(mem.read(hi - addr))
            break
    t0 = time.perf_counter()
    for _ in range(calls):
        run()
    seconds = (time.perf_counter() - t0) / calls
    total = int(n[active].sum())
    info = {"name": name, "addr": addr, "pixels": int(active.size), "samples": total}
    info["ns_per_sample"] = seconds * 1e9 / total
    (folder / "fn.json").write_text(json.dumps(info))


def instructions(folder: Path, name: str) -> tuple[list[int], list[str], list[int | None]]:
    """The kernel's instruction offsets and text (objdump) and each one's source line."""
    dump = subprocess.run(
        ["objdump", "-D", "-b", "binary", "-mi386:x86-64", str(folder / "code.bin")],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    offsets, texts = [], []
    for row in dump.splitlines():
        m = re.match(r"\s+([0-9a-f]+):\t[0-9a-f ]+\t(.*)", row)
        if m:
            offsets.append(int(m.group(1), 16))
            texts.append(m.group(2).strip())
    asm = (folder / "asm.s").read_text().splitlines()
    start = next(i for i, s in enumerate(asm) if s.startswith(name + ":"))
    listed, line = [], None
    for row in asm[start + 1 :]:
        if row.startswith(".Lfunc_end"):
            break
        m = re.match(r"\s*\.loc\s+\d+\s+(\d+)", row)
        if m:
            line = int(m.group(1)) or None
        elif row.startswith("\t") and not row.strip().startswith("."):
            listed.append((line, row.split()[0]))
    lines: list[int | None] = []
    k = 0
    for text in texts:
        if k == len(listed):
            break
        op = text.split()[0] if text else ""
        if (op.startswith("nop") or op in ("xchg", "data16", "cs")) and not listed[k][1].startswith(
            "nop"
        ):
            lines.append(None)  # alignment padding
            continue
        lines.append(listed[k][0])
        k += 1
    if k != len(listed):
        sys.exit(f"could not align the machine code with the assembly ({k} of {len(listed)})")
    n = len(lines)
    return offsets[:n], texts[:n], lines


def report(folder: Path, top: int) -> None:
    info = json.loads((folder / "fn.json").read_text())
    offsets, texts, lines = instructions(folder, info["name"])
    end = offsets[-1] + 16
    script = subprocess.run(
        ["perf", "script", "-i", str(folder / "perf.data"), "-F", "ip"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    hits = collections.Counter()
    for row in script.split():
        off = int(row, 16) - info["addr"]
        if 0 <= off < end:
            hits[bisect.bisect_right(offsets, off) - 1] += 1
    total = sum(hits.values())
    if not total:
        sys.exit("perf recorded no samples in the kernel")
    src = SOURCE.read_text().splitlines()
    stages = stage_lines(src)
    helpers = helper_ranges(src)

    def stage_of(line: int | None) -> str:
        if not line:
            return "(no line)"
        for a, b, stage in helpers:
            if a <= line <= b:
                return stage
        i = bisect.bisect_right([a for a, _ in stages], line) - 1
        return stages[i][1] if i >= 0 else "(outside)"

    def near(i: int) -> tuple:  # the source lines before and after a line-less instruction
        a = next((lines[j] for j in range(i, -1, -1) if lines[j]), None)
        b = next((lines[j] for j in range(i, len(lines)) if lines[j]), None)
        return a, b

    by_stage, by_line, unlined = collections.Counter(), collections.Counter(), collections.Counter()
    for i, v in hits.items():
        by_stage[stage_of(lines[i])] += v
        by_line[lines[i]] += v
        if not lines[i]:
            unlined[tuple(stage_of(x) for x in near(i))] += v
    print(
        f"{info['pixels']} pixels, {info['samples']} samples "
        f"({info['samples'] / info['pixels']:.1f} spp): {info['ns_per_sample']:.2f} ns per "
        f"sample on one thread; {total} timer samples in the kernel"
    )
    print("\nshare per stage:")
    for _, name in [(0, "(no line)"), *stages]:
        if by_stage[name]:
            print(f"  {100 * by_stage[name] / total:5.1f} %  {name}")
    print("  instructions without a line, by the stages around them:")
    for (a, b), v in unlined.most_common(5):
        print(f"  {100 * v / total:5.1f} %  between {a} and {b}")
    print(f"\ntop {top} source lines:")
    for line, v in by_line.most_common(top + 1):
        if line:
            print(f"  {100 * v / total:5.1f} %  {line:4d} {src[line - 1].strip()[:80]}")
    print(f"\ntop {top} instructions (a slow load shows on the one after it):")
    for i, v in hits.most_common(top):
        before = texts[i - 1] if i else ""
        print(
            f"  {100 * v / total:5.1f} %  line {lines[i]}: {texts[i][:48]:48s}  after {before[:40]}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("size", nargs="?", default="640x360")
    ap.add_argument("--counts", type=int, default=None, help="samples per SSS pixel")
    ap.add_argument("--calls", type=int, default=100)
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    size = tuple(int(v) for v in a.size.split("x"))
    if a.child:
        child(Path(a.child), size, a.counts, a.calls)
        return
    for tool in ("perf", "objdump"):
        if shutil.which(tool) is None:
            sys.exit(f"kernel_profile.py needs {tool!r} on the PATH")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        env = dict(os.environ, NUMBA_DEBUGINFO="1", NUMBA_CACHE_DIR=str(folder / "cache"))
        args = [sys.executable, __file__, a.size, "--calls", str(a.calls), "--child", tmp]
        if a.counts is not None:
            args += ["--counts", str(a.counts)]
        perf = ["perf", "record", "-q", "-e", "cpu-clock", "-F", "4000"]
        done = subprocess.run(
            [*perf, "-o", str(folder / "perf.data"), "--", *args],
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        if done.returncode or not (folder / "fn.json").exists():
            tail = "\n".join(done.stderr.strip().splitlines()[-5:])
            sys.exit(f"the profiled run failed (perf record exit {done.returncode}):\n{tail}")
        report(folder, a.top)


if __name__ == "__main__":
    main()
