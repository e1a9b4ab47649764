"""Custom-op attributes that contradict the tensors are refused when the model is loaded, on
both paths: the portable body of SoftmaxKernelApply with kernel_size=5 on 49-channel logits
used to give a finite, wrong image (issue 27, item 7)."""

from __future__ import annotations

import numpy as np
import onnx
import pytest

from rtdenoise.runtime import Denoiser, InputError
from rtdenoise.runtime.static_check import check_custom_nodes
from rtdenoise.shipped import demo_model


@pytest.mark.parametrize("model", ["afn", "wskp", "nbg", "affinity", "crossreg"])
def test_every_shipped_demo_passes(model):
    path = demo_model(model, ".onnx")
    assert check_custom_nodes(path.read_bytes(), str(path)) >= 2


def contradicting_afn(tmp_path, kernel_size: int = 5):
    m = onnx.load(demo_model("afn", ".onnx"))
    node = next(n for n in m.graph.node if n.op_type == "SoftmaxKernelApply")
    next(a for a in node.attribute if a.name == "kernel_size").i = kernel_size
    path = tmp_path / "afn_k5.onnx"
    onnx.save(m, path)
    return path, node.name


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "portable"])
def test_kernel_size_against_logit_channels_is_refused_at_load(tmp_path, fast):
    path, name = contradicting_afn(tmp_path)
    with pytest.raises(InputError) as info:
        Denoiser(path, fast_kernels=fast)
    text = str(info.value)
    assert str(path) in text and f"node {name!r} (SoftmaxKernelApply) contradicts" in text
    assert "49" in text and "'kernel_size': 5" in text and "\n" not in text
    with pytest.raises(InputError, match="contradicts its inputs"):
        Denoiser(path.read_bytes(), fast_kernels=fast)


def test_before_the_check_the_portable_path_gave_a_wrong_finite_image(tmp_path, monkeypatch):
    """What the check prevents: with it bypassed the portable body runs and returns finite
    values (the fast path raises at run)."""
    import rtdenoise.runtime.session as session_module

    path, _ = contradicting_afn(tmp_path)
    monkeypatch.setattr(session_module, "check_custom_nodes", lambda *a: 0)
    den = Denoiser(path, fast_kernels=False, threads=1)
    rng = np.random.default_rng(0)
    frame = {
        "color": rng.random((3, 32, 32), dtype=np.float32),
        "albedo": np.full((3, 32, 32), 0.5, np.float32),
        "normal": np.zeros((3, 32, 32), np.float32) + [[[0.0]], [[0.0]], [[1.0]]],
        "depth": np.ones((1, 32, 32), np.float32),
        "motion": np.zeros((2, 32, 32), np.float32),
    }
    frame["normal"] = frame["normal"].astype(np.float32)
    assert np.isfinite(den.process(frame)).all()
