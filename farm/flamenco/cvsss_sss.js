// SPDX-License-Identifier: GPL-3.0-or-later
//
// Flamenco 3 job type for cvsss: the passes of a .blend in frame chunks (one Blender
// process per chunk, on any number of Flamenco workers), then the post-process on one
// worker with `cvsss post --workers`, the tiled post on a local Dask cluster of that
// worker (identical bit for bit to `cvsss post`). The same job as farm/openjd.
//
// UNTESTED HERE: no Flamenco Manager runs in this repository's tests (the Open Job
// Description bundle is the tested one). Install: copy this file into the `scripts/`
// folder next to the flamenco-manager executable and restart it. Every worker needs
// cvsss installed with its farm extra (pip install 'cvsss[farm]' in a Python 3.11 with
// bpy 5.0.1; `python` names that interpreter) and the .blend and output folder at the
// same paths (Flamenco's shared storage).

const JOB_TYPE = {
  label: "cvsss Subsurface Scattering",
  description:
    "Screen-space subsurface scattering of a sequence: passes in frame chunks, then the " +
    "temporal post-process split into image tiles on one worker.",
  settings: [
    { key: "python", type: "string", default: "python3", description: "Python with cvsss[farm] and bpy" },
    { key: "filepath", type: "string", subtype: "file_path", required: true, description: "The .blend" },
    { key: "frames", type: "string", required: true, description: "Frame range, e.g. 1-240" },
    { key: "chunk_size", type: "int32", default: 8, description: "Frames per pass-rendering task" },
    { key: "output_dir", type: "string", subtype: "dir_path", required: true, description: "Output folder" },
    { key: "methods", type: "string", default: "as_ccv", description: "cvsss post --method" },
    { key: "post_workers", type: "int32", default: 2, description: "Dask worker processes of the post" },
    { key: "tile", type: "int32", default: 256, description: "Tile side in pixels of the post" },
    { key: "post_args", type: "string", default: "", description: "More cvsss post flags, space-separated" },
  ],
};

function compileJob(job) {
  const settings = job.settings;
  const first = firstFrame(settings.frames);
  const passTasks = [];
  for (const chunk of frameChunker(settings.frames, settings.chunk_size)) {
    const task = author.Task(`passes-${chunk}`, "blender");
    task.addCommand(
      author.Command("exec", {
        exe: settings.python,
        args: [
          "-m", "cvsss.sss_addon.cli.main", "render", settings.filepath,
          "--frames", chunk,
          "--out", settings.output_dir,
          "--passes-only",
          // The ground truth (when the .blend asks for it) falls on every k-th frame of
          // the whole range, not of the chunk.
          "--range-start", String(first),
          "--quiet",
        ],
      })
    );
    passTasks.push(task);
    job.addTask(task);
  }

  const post = author.Task("post", "misc");
  const extra = settings.post_args.split(" ").filter((a) => a.length > 0);
  post.addCommand(
    author.Command("exec", {
      exe: settings.python,
      args: [
        "-m", "cvsss.sss_addon.cli.main", "post", path.join(settings.output_dir, "passes"),
        "--out", settings.output_dir,
        "--method", settings.methods,
        "--workers", String(settings.post_workers),
        "--tile", String(settings.tile),
        "--resume", // a requeued post continues after each method's checkpoint
        "--quiet",
        ...extra,
      ],
    })
  );
  for (const task of passTasks) {
    post.addDependency(task);
  }
  job.addTask(post);
}

// First frame of a Flamenco frame range such as "1-240" or "1-10,20-30".
function firstFrame(frames) {
  const numbers = frames.split(/[,-]/).map((s) => parseInt(s, 10)).filter((n) => !isNaN(n));
  return Math.min(...numbers);
}
