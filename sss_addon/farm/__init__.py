"""Scale-out on Dask distributed: chunked pass rendering and the tiled post (issue 16).

Needs the optional extra ``cvsss[farm]`` (Dask distributed, Open Job
Description's CLI); nothing here is imported by the Blender extension, and
Dask is imported only when a command asks for workers. The computation itself
lives in core (core.tiling: bit-identical tiles; core.run: the sequence
driver); this package only schedules it:

- :mod:`.cluster`: a local cluster on 127.0.0.1 (``--workers N``) or an
  existing scheduler (``--scheduler tcp://HOST:PORT``), and the executor that
  hands core.tiling's jobs to it;
- :mod:`.post`: ``cvsss post --workers``, the tiled post on the cluster;
- :mod:`.passes`: ``cvsss render --workers``, pass rendering in frame chunks,
  one Blender process per chunk.
"""
