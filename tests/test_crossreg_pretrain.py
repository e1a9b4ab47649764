"""crossreg's initial theta pretrained offline (`denoise-train --family crossreg`): the outer loop
runs every clip with the online update frozen, theta is the U-Net's parameters on every frame and
the supervised loss reaches them through each frame's output; the checkpoint's U-Net is then the
initial theta of the online learner."""

from __future__ import annotations

import torch
from train_data import write_sequence

from rtdenoise.models.checkpoint import load_checkpoint
from rtdenoise.models.families.crossreg import CrossReg
from rtdenoise.models.frame_loop import FrameLoop, unroll
from rtdenoise.models.registry import build_model
from rtdenoise.models.train import TrainSettings, train

SMALL = CrossReg.example_config


def _clip(frames: int, size: int = 32, motion: float = 0.0) -> dict[str, torch.Tensor]:
    """(1, T, C, H, W) noisy random buffers; `motion` in pixels (1000: no history anywhere)."""
    gen = torch.Generator().manual_seed(0)

    def rand(c: int) -> torch.Tensor:
        return torch.rand(1, frames, c, size, size, generator=gen)

    normal = torch.nn.functional.normalize(rand(3) - 0.5, dim=2)
    return {
        "color": rand(3) * 2.0,
        "color_b": rand(3) * 2.0,
        "albedo": rand(3),
        "normal": normal,
        "depth": 1.0 + rand(1),
        "motion": torch.full((1, frames, 2, size, size), motion),
    }


def test_the_outer_gradient_reaches_the_parameters_on_every_frame():
    """Frame 2 has no history (motion off-screen): its output depends on frame 2's theta only,
    so its gradient in the unroll must be the one of the same frame run alone. It would be zero
    if frame 2's theta were the (detached) state the online step left, not the parameters."""
    model = build_model("crossreg", SMALL).train()
    clip = _clip(3, motion=1000.0)
    params = list(model.unet.parameters())
    out = unroll(model, clip)
    unrolled = torch.autograd.grad(out[:, 2].sum(), params)
    alone = FrameLoop(model, outer=True)({k: v[:, 2] for k, v in clip.items()})
    single = torch.autograd.grad(alone.sum(), params)
    assert float(sum(g.abs().sum() for g in unrolled)) > 0.0
    for a, b in zip(unrolled, single, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
    # the online update stayed off: theta is still the parameters, Adam untouched
    loop = FrameLoop(model, outer=True)
    for t in range(3):
        loop({k: v[:, t] for k, v in clip.items()})
    state = loop.state
    torch.testing.assert_close(state["theta"].reshape(-1), model.layout.flatten(model.unet))
    assert state["theta"].requires_grad and float(state["adam_t"].sum()) == 0.0


def test_the_history_carries_the_outer_gradient():
    """With a static camera, frame 1's output blends frame 0's: the gradient through the
    history differs from frame 1 run alone."""
    model = build_model("crossreg", SMALL).train()
    clip = _clip(2)
    params = list(model.unet.parameters())
    out = unroll(model, clip)
    unrolled = torch.autograd.grad(out[:, 1].sum(), params)
    alone = FrameLoop(model, outer=True)({k: v[:, 1] for k, v in clip.items()})
    single = torch.autograd.grad(alone.sum(), params)
    assert any(not torch.allclose(a, b) for a, b in zip(unrolled, single, strict=True))


def test_eval_and_no_grad_still_learn_online():
    """Outside the outer loop the zero state is the executor's: the online step runs."""
    model = build_model("crossreg", SMALL).eval()
    clip = _clip(2)
    loop = FrameLoop(model)
    with torch.no_grad():
        for t in range(2):
            loop({k: v[:, t] for k, v in clip.items()})
    assert float(loop.state["adam_t"].reshape(-1)[0]) == 2.0
    assert not loop.state["theta"].requires_grad


def test_denoise_train_pretrains_the_initial_theta(tmp_path):
    data = write_sequence(tmp_path / "seq", frames=4, size=32, color_b=True)
    settings = TrainSettings(
        steps=2, crop=16, frames=3, batch=1, lr=1e-2, seed=1, save_every=0, threads=1
    )
    result = train(
        [data],
        tmp_path / "x.pt",
        family="crossreg",
        model_config=SMALL,
        settings=settings,
        progress=False,
        log=lambda _: None,
    )
    assert len(result.losses) == 2 and all(torch.isfinite(torch.tensor(result.losses)))
    model, meta = load_checkpoint(tmp_path / "x.pt")
    init = build_model("crossreg", SMALL)
    trained, fresh = model.layout.flatten(model.unet), init.layout.flatten(init.unet)
    assert not torch.allclose(trained, fresh)
    assert meta["settings"]["recipe"] == "default" and "command" in meta
    # the online learner starts from the trained U-Net: frame 0's displayed output uses it
    clip = _clip(1)
    frame = {k: v[:, 0] for k, v in clip.items()}
    with torch.no_grad():
        a, b = FrameLoop(model)(frame), FrameLoop(init)(frame)
    assert not torch.allclose(a, b)
