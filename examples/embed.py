"""The README's "Embed the runtime" snippet, as a program: denoise one shot's EXR frames.

    python examples/embed.py SHOT_FOLDER OUT_FOLDER [LAYOUT]

Tested by tests/test_examples.py, which also checks that the README shows this code as is.
"""

import sys
from pathlib import Path

from rtdenoise.runtime import Denoiser, iter_sequence, write_output

shot, out = Path(sys.argv[1]), Path(sys.argv[2])  # frames frame_NNNN.exr; the output folder
layout = sys.argv[3] if len(sys.argv) > 3 else "canonical"  # blender, or my_renderer.toml

denoiser = Denoiser("demo:afn")  # or "model.onnx"; fast_kernels=False: the portable path
# (denoiser.bridge: "native", the zero-copy default, or "extensions" where it was not built)
for frame in iter_sequence(shot, layout, buffers=denoiser.required_buffers):
    rgb = denoiser.process(frame.buffers)  # (3, H, W) float32, linear HDR; state carried inside
    write_output(out / frame.path.name, rgb)  # R,G,B half float, written atomically
denoiser.reset()  # a camera cut: the next frame starts a new history (also on a size change)
