"""The `padding` and `edge_margin` config keys of afn, affinity and nbg: how their k x k convs
see past the frame's edge, and how far past it the frame is extended first."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from model_inputs import random_buffers

from rtdenoise.export.onnx_export import export_model
from rtdenoise.export.validate import synthetic_frames, validate
from rtdenoise.models.frame_loop import FrameLoop
from rtdenoise.models.registry import build_model, family_class

CONFIGS = {
    "afn": {"widths": [8, 12, 16], "kernel_size": 5, "refine_width": 8, "fusion": "network"},
    "affinity": family_class("affinity").example_config,
    "nbg": {"hidden": 8, "guide_tonemap": "log1p", "reprojection": "per_tap_hdr"},
}
N, H, W = 1, 32, 32


def _edge_pad(a: np.ndarray, m: int) -> np.ndarray:
    """`a` ((C, H, W) or (S, C, H, W)) with m edge pixels repeated on every side."""
    return np.pad(a, ((0, 0),) * (a.ndim - 2) + ((m, m), (m, m)), mode="edge")


def _conv_outputs(model: torch.nn.Module, buffers: dict) -> list[torch.Tensor]:
    """The outputs of the model's k x k convs on one first frame, in call order."""
    outputs: list[torch.Tensor] = []
    convs = [
        m for m in model.modules() if isinstance(m, torch.nn.Conv2d) and m.kernel_size != (1, 1)
    ]
    hooks = [c.register_forward_hook(lambda m, i, o: outputs.append(o)) for c in convs]
    model(buffers, model.initial_state(N, H, W), torch.tensor(1.0))
    for hook in hooks:
        hook.remove()
    return outputs


@pytest.mark.parametrize("family", sorted(CONFIGS))
def test_replicate_padding_changes_the_edge_and_exports(family: str):
    """padding="replicate": every k x k conv repeats the frame's edge pixel instead of reading
    zeros past it (1 x 1 convs unchanged); with the same weights every k x k conv's output
    changes at the frame's edge (the first conv's only there), and ORT (fast and portable)
    follows PyTorch over moving frames with state. An unknown mode is refused by name."""
    config = CONFIGS[family]
    torch.manual_seed(0)
    zeros = build_model(family, config).eval().requires_grad_(False)
    replicate = build_model(family, {**config, "padding": "replicate"}).eval()
    replicate.load_state_dict(zeros.state_dict())
    replicate.requires_grad_(False)
    convs = [m for m in replicate.modules() if isinstance(m, torch.nn.Conv2d)]
    assert {m.padding_mode for m in convs if m.kernel_size != (1, 1)} == {"replicate"}
    assert all(m.padding_mode == "zeros" for m in convs if m.kernel_size == (1, 1))
    assert replicate.config()["padding"] == "replicate" and zeros.config()["padding"] == "zeros"
    buffers = random_buffers(0, N, H, W)
    a, b = (_conv_outputs(m, buffers) for m in (zeros, replicate))
    edge = [float((x - y)[..., 0].abs().max()) for x, y in zip(a, b, strict=True)]
    inner = [float((x - y)[..., 8:-8, 8:-8].abs().max()) for x, y in zip(a[:1], b[:1], strict=True)]
    assert min(edge) > 1e-4 and inner == [0.0]  # the first conv: only its edge changes
    report = validate(
        replicate,
        export_model(replicate).SerializeToString(),
        synthetic_frames(replicate.inputs, 3, 32, 32),
    )
    assert report.passed and report.max_error < 1e-5, report.errors
    with pytest.raises(ValueError, match=f"{family} padding must be one of zeros, replicate"):
        build_model(family, {**config, "padding": "reflect"})


@pytest.mark.parametrize("family", sorted(CONFIGS))
def test_edge_margin_runs_the_model_on_the_edge_padded_frame(family: str):
    """`edge_margin` = 6: FrameLoop repeats 6 edge pixels on every side (then pads to the pad
    multiple) and crops the output back, i.e. exactly the margin-0 model with the same weights
    on np.pad(frame, 6, "edge"), cropped, over 4 moving frames with state at a size that is no
    multiple (30 x 37); exported, the key `rtdenoise.edge_margin` carries it, ORT (fast and
    portable) follows PyTorch, and out-of-range margins are refused by name."""
    m, (h, w) = 6, (30, 37)
    config = {**CONFIGS[family], "padding": "replicate"}
    torch.manual_seed(0)
    plain = build_model(family, config).eval().requires_grad_(False)
    margin = build_model(family, {**config, "edge_margin": m}).eval().requires_grad_(False)
    margin.load_state_dict(plain.state_dict())
    assert margin.edge_margin == m and margin.config()["edge_margin"] == m
    frames = synthetic_frames(plain.inputs, 4, h, w)
    padded = [{k: _edge_pad(v, m) for k, v in f.items()} for f in frames]
    with torch.no_grad():
        ours = [o[0].numpy() for o in FrameLoop(margin).run(frames)]
        theirs = [o[0, :, m : m + h, m : m + w].numpy() for o in FrameLoop(plain).run(padded)]
        unpadded = [o[0].numpy() for o in FrameLoop(plain).run(frames)]
    for a, b in zip(ours, theirs, strict=True):
        assert a.shape == (3, h, w)
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)
    assert max(float(np.abs(a - c).max()) for a, c in zip(ours, unpadded, strict=True)) > 1e-3
    proto = export_model(margin)
    assert {p.key: p.value for p in proto.metadata_props}["rtdenoise.edge_margin"] == str(m)
    report = validate(margin, proto.SerializeToString(), frames)
    assert report.passed and report.max_error < 1e-4, report.errors
    for bad in (-1, 257, 2.5):
        with pytest.raises(ValueError, match=f"{family} edge_margin must be"):
            build_model(family, {**config, "edge_margin": bad})
