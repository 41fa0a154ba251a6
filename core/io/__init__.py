"""Files: pass and result EXRs, sidecars, atomic writes and checkpoints."""
