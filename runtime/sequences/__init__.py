"""rtdenoise.runtime.sequences: EXR frame sequences around the executor (`denoise-run`'s wing).

EXR files (`exr`), channel layouts (`layouts`), finding and reading frames and writing outputs
(`frames`), per-sample layers (`samples`), atomic file writes (`atomic`), the sequence runner
(`run`, `backend`) and its Ray form (`cluster`), metrics (`metrics`), previews (`preview`),
the side-by-side comparison with Open Image Denoise (`compare`) and synthetic frames
(`synthetic`). It may import the host wing (`rtdenoise.runtime`); neither the host wing nor the
bridge wing imports it. Never imports torch.
"""
