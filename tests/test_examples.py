"""examples/: the README's embed snippet runs as written; a host with nothing but onnxruntime
and numpy drives the shipped models exactly as `Denoiser` does (docs/contract.md)."""

from __future__ import annotations

import ast
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from shipped_demos import SHIPPED_DEMOS

from rtdenoise.runtime import Denoiser, iter_sequence, read_exr
from rtdenoise.shipped import MODELS_DIR, sample_sequences

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"


def load_example(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def code_of(path: Path) -> str:
    """A script without its module docstring: what the README shows."""
    text = path.read_text()
    docstring = ast.get_docstring(ast.parse(text), clean=False)
    return text.split(f'"""{docstring}"""', 1)[1].strip() if docstring else text.strip()


def test_readme_embed_snippet_is_the_example(tmp_path):
    """The README shows examples/embed.py as is, and it runs: 8 frames denoised and written."""
    assert f"```python\n{code_of(EXAMPLES / 'embed.py')}\n```" in (ROOT / "README.md").read_text()
    shot, out = sample_sequences()[0], tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, str(EXAMPLES / "embed.py"), str(shot), str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    den = Denoiser("demo:afn")
    for frame in iter_sequence(shot, buffers=den.required_buffers):
        expected = den.process(frame.buffers).astype(np.float16)
        got = read_exr(out / frame.path.name)
        np.testing.assert_array_equal(np.stack([got[c] for c in "RGB"]), expected)


def test_the_demos_are_the_shipped_files():
    assert sorted(p.stem for p in MODELS_DIR.glob("*.onnx")) == sorted(SHIPPED_DEMOS)


def test_plain_host_imports_only_onnxruntime_and_numpy():
    path = EXAMPLES / "plain_onnxruntime_host.py"
    imported = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add((node.module or "").split(".")[0])
    assert imported == {"__future__", "collections", "json", "sys", "numpy", "onnxruntime"}


@pytest.mark.parametrize("demo", SHIPPED_DEMOS)
def test_plain_host_runs_every_demo_without_rtdenoise(demo):
    """Its own main (synthetic frames: 2 samples per pixel for affinity), rtdenoise blocked."""
    path = EXAMPLES / "plain_onnxruntime_host.py"
    code = (
        "import runpy, sys; sys.modules['rtdenoise'] = None; "
        f"sys.argv = ['host', {str(MODELS_DIR / f'{demo}.onnx')!r}, '3']; "
        f"runpy.run_path({str(path)!r}, run_name='__main__')"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("output (3, 48, 64)") == 3


@pytest.mark.parametrize("demo", SHIPPED_DEMOS)
@pytest.mark.parametrize("fast_kernels", [True, False])
def test_plain_host_matches_denoiser_over_8_frames(demo, fast_kernels):
    """The same 8 frames with a camera cut before frame 5: equal within 1e-5, state fed back
    (a host that knows nothing of online learning zeroes every state at a cut, so it restarts
    crossreg's learning there, as `Denoiser(relearn_at_cuts=True)` does)."""
    plain = load_example("plain_onnxruntime_host")
    model = MODELS_DIR / f"{demo}.onnx"
    host = plain.PlainHost(str(model))
    den = Denoiser(model, fast_kernels=fast_kernels, relearn_at_cuts=True)
    frames = list(iter_sequence(sample_sequences()[0], buffers=den.required_buffers))
    assert len(frames) == 8
    worst = 0.0
    for i, frame in enumerate(frames):
        if i == 5:
            host.reset()
            den.reset()
        buffers = frame.buffers
        if demo.startswith("affinity"):  # the host makes S = 1 itself, from the pixel buffers
            buffers = {k: v for k, v in buffers.items() if k != "samples"}
        ours, theirs = host.process(buffers), den.process(frame.buffers)
        worst = max(worst, float(np.max(np.abs(ours - theirs) / (1 + np.abs(theirs)))))
    assert worst <= 1e-5, worst


def test_plain_host_feeds_several_samples_as_denoiser_does():
    """affinity with S = 2 per-sample frames (rank 5), as Denoiser reads them."""
    plain = load_example("plain_onnxruntime_host")
    host = plain.PlainHost(str(MODELS_DIR / "affinity.onnx"))
    den = Denoiser(MODELS_DIR / "affinity.onnx", fast_kernels=False)
    for t in range(3):
        frame = plain.synthetic_frame(host.buffers, t, 32, 40, host.sample_features, spp=2)
        assert frame["samples"].shape == (2, 10, 32, 40)
        np.testing.assert_allclose(host.process(frame), den.process(frame), rtol=1e-5, atol=1e-5)


def test_plain_host_restarts_on_a_size_change():
    """Padding and a new history at a new size, as `Denoiser` on the same (portable) path."""
    plain = load_example("plain_onnxruntime_host")
    host = plain.PlainHost(str(MODELS_DIR / "wskp.onnx"))
    den = Denoiser(MODELS_DIR / "wskp.onnx", fast_kernels=False)
    for t, (h, w) in enumerate([(24, 40), (24, 40), (33, 21), (33, 21)]):
        frame = plain.synthetic_frame(host.buffers, t, h, w)
        np.testing.assert_allclose(host.process(frame), den.process(frame), rtol=1e-6, atol=1e-6)


def test_plain_host_applies_an_edge_margin_as_denoiser_does(tmp_path):
    """demo:afn (pad multiple 16) given `rtdenoise.edge_margin` = 5: the host pads 5 edge
    pixels on every side, then to the multiple, and crops from (5, 5), as `Denoiser` does;
    both differ from the same model without the margin."""
    import onnx

    plain = load_example("plain_onnxruntime_host")
    proto = onnx.load(str(MODELS_DIR / "afn.onnx"))
    proto.metadata_props.add(key="rtdenoise.edge_margin", value="5")
    path = tmp_path / "afn_margin.onnx"
    onnx.save(proto, str(path))
    host, den = plain.PlainHost(str(path)), Denoiser(path, fast_kernels=True)
    without = Denoiser(MODELS_DIR / "afn.onnx", fast_kernels=True)
    assert host.margin == den.edge_margin == 5 and without.edge_margin == 0
    for t in range(3):
        frame = plain.synthetic_frame(host.buffers, t, 30, 37)
        ours, theirs = host.process(frame), den.process(frame)
        np.testing.assert_allclose(ours, theirs, rtol=1e-5, atol=1e-5)
    assert den.state_value("ta").shape[-2:] == (48, 48)  # 30 + 10, 37 + 10 -> multiples of 16
    assert float(np.abs(theirs - without.process(frame)).max()) > 1e-3
