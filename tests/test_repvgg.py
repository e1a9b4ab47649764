"""RepVGG blocks (Fan21 s.1.1): the folded 5 x 5 conv equals the multi-branch block."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from rtdenoise.export.deploy import to_deploy
from rtdenoise.models.families.wskp import WSKP
from rtdenoise.models.repvgg import RepVGGBlock, fold_bn, identity_kernel, pad_kernel


def _randomise(module: nn.Module, seed: int, scale: float = 0.2, shift: float = 1.0) -> None:
    """Random weights (std `scale`), biases and non-trivial BN running statistics (gamma,
    beta, mean, var; offsets of std `shift`)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in module.modules():
            if isinstance(m, nn.Conv2d):
                m.weight.copy_(torch.randn(m.weight.shape, generator=g) * scale)
                if m.bias is not None:
                    m.bias.copy_(torch.randn(m.bias.shape, generator=g) * shift)
            elif isinstance(m, nn.BatchNorm2d):
                c = m.num_features
                m.weight.copy_(0.5 + torch.rand(c, generator=g) * 1.5)
                m.bias.copy_(torch.randn(c, generator=g) * shift)
                m.running_mean.copy_(torch.randn(c, generator=g) * shift)
                m.running_var.copy_(0.1 + torch.rand(c, generator=g) * 3.0)


def _rel(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max() / b.abs().max())


CASES = [  # in, out, bn, bias, kernel sizes, identity expected
    (8, 8, False, False, (5, 3, 1), True),
    (6, 9, False, False, (5, 3, 1), False),
    (8, 8, True, False, (5, 3, 1), True),
    (8, 8, True, True, (5, 3, 1), True),
    (6, 9, True, True, (5, 3, 1), False),
    (7, 7, False, True, (5, 3, 1), True),
    (5, 5, True, False, (3, 1), True),
]


@pytest.mark.parametrize(("c_in", "c_out", "bn", "bias", "sizes", "has_id"), CASES)
def test_fold_is_exact(c_in, c_out, bn, bias, sizes, has_id):
    block = RepVGGBlock(c_in, c_out, sizes, bn=bn, bias=bias)
    assert (block.identity is not None) == has_id
    _randomise(block, seed=c_in + 10 * c_out + 100 * bn + 1000 * bias)
    block.eval()
    x = torch.randn(2, c_in, 17, 13, generator=torch.Generator().manual_seed(1)) * 2.0
    conv = block.reparameterize()
    k = max(sizes)
    assert isinstance(conv, nn.Conv2d)
    assert conv.kernel_size == (k, k) and conv.padding == (k // 2, k // 2)
    assert (conv.bias is not None) == (bn or bias)
    with torch.no_grad():
        ref, out = block(x), conv(x)
        assert _rel(out, ref) < 1e-5
        # the small branches and the identity matter: the largest conv alone is far off
        only_big = block.branches[0](x)
        assert _rel(only_big, ref) > 0.05


def test_fold_bn_matches_conv_then_bn():
    conv = nn.Conv2d(4, 6, 3, padding=1, bias=True)
    bn = nn.BatchNorm2d(6)
    seq = nn.Sequential(conv, bn)
    _randomise(seq, seed=3)
    seq.eval()
    w, b = fold_bn(conv.weight.double(), conv.bias.double(), bn)
    x = torch.randn(1, 4, 9, 9, dtype=torch.float64)
    with torch.no_grad():
        ref = seq.double()(x)
        out = nn.functional.conv2d(x, w, b, padding=1)
    torch.testing.assert_close(out, ref, rtol=1e-12, atol=1e-12)


def test_kernel_helpers():
    w = torch.arange(9.0).view(1, 1, 3, 3)
    padded = pad_kernel(w, 5)
    assert padded.shape == (1, 1, 5, 5)
    assert torch.equal(padded[0, 0, 1:4, 1:4], w[0, 0]) and float(padded.abs().sum()) == 36.0
    ident = identity_kernel(3, 5)
    x = torch.randn(1, 3, 6, 7)
    torch.testing.assert_close(nn.functional.conv2d(x, ident, padding=2), x, rtol=0, atol=0)


def test_block_arguments():
    assert RepVGGBlock(4, 4).identity is not None
    assert RepVGGBlock(4, 4, identity=False).identity is None
    assert isinstance(RepVGGBlock(4, 4, bn=True).identity, nn.BatchNorm2d)
    assert [b[0].kernel_size[0] for b in RepVGGBlock(4, 6).branches] == [5, 3, 1]
    with pytest.raises(ValueError, match="in_ch == out_ch"):
        RepVGGBlock(4, 6, identity=True)
    with pytest.raises(ValueError, match="odd"):
        RepVGGBlock(4, 4, (5, 2))


def test_to_deploy_folds_a_whole_wskp_model():
    """Generic deploy pass on WSKP with BN and biases: same output, only 5 x 5 convs left."""
    model = WSKP({"bn": True, "bias": True, "width": 8})
    # weights of a trained net's size (logits of a few units): exp() of the importance logits
    # turns an absolute logit error e into a relative weight error e, so huge random logits
    # (thousands) would test float32 rounding, not the fold
    _randomise(model, seed=7, scale=0.04, shift=0.2)
    model.eval()
    deployed = to_deploy(model)
    kinds = {type(m) for m in deployed.modules()}
    assert RepVGGBlock not in kinds and nn.BatchNorm2d not in kinds
    convs = [m for m in deployed.modules() if isinstance(m, nn.Conv2d)]
    assert len(convs) == 6 and all(c.kernel_size == (5, 5) for c in convs)
    assert any(isinstance(m, RepVGGBlock) for m in model.modules())  # original untouched
    g = torch.Generator().manual_seed(5)
    h, w = 24, 20
    buffers = {
        "color": torch.rand(1, 3, h, w, generator=g) * 3.0,
        "albedo": torch.rand(1, 3, h, w, generator=g),
        "normal": nn.functional.normalize(torch.randn(1, 3, h, w, generator=g), dim=1),
        "depth": 1.0 + torch.rand(1, 1, h, w, generator=g),
        "motion": torch.zeros(1, 2, h, w),
    }
    state = model.initial_state(1, h, w)
    with torch.no_grad():
        net_in = torch.rand(1, 10, h, w, generator=g)
        ref_logits = model.importance_net(net_in)
        out_logits = deployed.importance_net(net_in)
        ref, _ = model(buffers, state, torch.tensor(1.0))
        out, _ = deployed(buffers, state, torch.tensor(1.0))
    assert 1.0 < float(ref_logits.abs().max()) < 50.0
    assert _rel(out_logits, ref_logits) < 1e-5
    assert _rel(out, ref) < 1e-5
