"""farm/flamenco: the job type compiles to pass chunks and one post (Node, mocked Flamenco API).

Flamenco itself is not run here (documented as untested); this only checks the
script's syntax and the tasks it authors, with stand-ins for Flamenco's
``author``, ``path`` and ``frameChunker``.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "farm" / "flamenco" / "cvsss_sss.js"

HARNESS = r"""
const fs = require("fs");
const vm = require("vm");
const tasks = [];
const sandbox = {
  author: {
    Task: (name, type) => ({ name, type, commands: [], deps: [],
      addCommand(c) { this.commands.push(c); }, addDependency(t) { this.deps.push(t.name); } }),
    Command: (kind, params) => ({ kind, params }),
  },
  path: { join: (...p) => p.join("/") },
  frameChunker: (frames, size) => {
    const [a, b] = frames.split("-").map(Number);
    const out = [];
    for (let s = a; s <= b; s += size) out.push(s === Math.min(s + size - 1, b) ? `${s}` : `${s}-${Math.min(s + size - 1, b)}`);
    return out;
  },
};
vm.createContext(sandbox);
vm.runInContext(fs.readFileSync(process.argv[2], "utf8") + "\nthis.JOB_TYPE = JOB_TYPE;", sandbox);
const settings = {};
for (const s of sandbox.JOB_TYPE.settings) if ("default" in s) settings[s.key] = s.default;
Object.assign(settings, { filepath: "/s/scene.blend", frames: "3-12", output_dir: "/s/out" });
sandbox.compileJob({ settings, addTask: (t) => tasks.push(t) });
console.log(JSON.stringify(tasks));
"""


@pytest.mark.skipif(shutil.which("node") is None, reason="needs Node.js")
def test_job_type_authors_chunks_then_post(tmp_path):
    harness = tmp_path / "harness.js"
    harness.write_text(HARNESS)
    run = subprocess.run(
        ["node", str(harness), str(SCRIPT)], capture_output=True, text=True, timeout=30, check=False
    )
    assert run.returncode == 0, run.stderr
    tasks = json.loads(run.stdout)
    assert [t["name"] for t in tasks] == ["passes-3-10", "passes-11-12", "post"]
    chunk = tasks[0]["commands"][0]["params"]["args"]
    assert chunk[chunk.index("--frames") + 1] == "3-10" and "--passes-only" in chunk
    assert chunk[chunk.index("--range-start") + 1] == "3"
    post = tasks[-1]
    assert post["deps"] == ["passes-3-10", "passes-11-12"]
    args = post["commands"][0]["params"]["args"]
    assert args[2:4] == ["post", "/s/out/passes"] and "--workers" in args and "--resume" in args
