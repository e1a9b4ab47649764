"""torch -> ONNX with the rtdenoise custom nodes: a tiny module calling both ops exports
(dynamo, dynamic H and W) to one custom node per call, passes the full checker, and runs in
ONNX Runtime on the fast path and the portable path (function bodies) matching torch
within 1e-5 at two resolutions."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from rtdenoise.export import ops as eops
from rtdenoise.export.onnx_export import to_onnx
from rtdenoise.models import ops as tops
from rtdenoise.models.ops.adaptive_fusion import adaptive_fusion
from rtdenoise.models.ops.kernel_apply import kernel_apply
from rtdenoise.runtime import bridge as fast_bridge

TOL = 1e-5


class Tiny(nn.Module):
    """Predict a 5x5 kernel and a blend weight; filter twice, fuse with a half-res image."""

    def __init__(self) -> None:
        super().__init__()
        torch.manual_seed(0)
        self.kernel_net = nn.Conv2d(3, 25, 3, padding=1)
        self.alpha_net = nn.Conv2d(3, 1, 3, padding=1)

    def forward(self, color: torch.Tensor) -> torch.Tensor:
        kernel = torch.softmax(self.kernel_net(color), dim=1)
        filtered = kernel_apply(color, kernel, dilation=2)
        filtered = kernel_apply(filtered, kernel, dilation=1)
        low = F.avg_pool2d(color, 2)
        alpha = torch.sigmoid(self.alpha_net(color))
        return adaptive_fusion(filtered, low, alpha)


@pytest.fixture(scope="module")
def exported() -> tuple[nn.Module, onnx.ModelProto]:
    module = Tiny().eval()
    h2, w2 = torch.export.Dim("h2", min=2, max=1024), torch.export.Dim("w2", min=2, max=1024)
    model = to_onnx(
        module,
        (torch.rand(1, 3, 16, 24),),
        dynamic_shapes={"color": {2: 2 * h2, 3: 2 * w2}},
        input_names=["color"],
        output_names=["output"],
    )
    return module, model


def test_one_custom_node_per_call_and_functions(exported):
    _, model = exported
    onnx.checker.check_model(model, full_check=True)
    custom = [n for n in model.graph.node if n.domain == "rtdenoise"]
    assert [n.op_type for n in custom] == ["KernelApply", "KernelApply", "AdaptiveFusion"]
    attrs = [{a.name: a.i for a in n.attribute} for n in custom[:2]]
    assert attrs == [{"kernel_size": 5, "dilation": 2}, {"kernel_size": 5, "dilation": 1}]
    assert sorted(f.name for f in model.functions) == ["AdaptiveFusion", "KernelApply"]
    assert {i.domain: i.version for i in model.opset_import} == {"": 18, "rtdenoise": 1}
    assert model.ir_version == 10
    dims = [d.dim_param or d.dim_value for d in model.graph.input[0].type.tensor_type.shape.dim]
    assert dims[:2] == [1, 3] and all(isinstance(d, str) for d in dims[2:])  # dynamic H, W
    # attach_functions is idempotent
    again = eops.attach_functions(onnx.ModelProto.FromString(model.SerializeToString()))
    assert len(again.functions) == 2


@pytest.mark.parametrize("fast", [True, False], ids=["fast", "portable"])
def test_ort_matches_torch_at_two_sizes(exported, fast):
    module, model = exported
    so = ort.SessionOptions()
    if fast:
        fast_bridge.register_fast_kernels(so)
    sess = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(5)
    for h, w in [(20, 26), (32, 48)]:
        color = rng.random((1, 3, h, w), dtype=np.float32)
        before = fast_bridge.CALLS["KernelApply"]
        (out,) = sess.run(None, {"color": color})
        assert fast_bridge.CALLS["KernelApply"] - before == (2 if fast else 0)
        with torch.no_grad():
            ref = module(torch.from_numpy(color)).numpy()
        assert out.shape == (1, 3, h, w)
        assert np.abs(out - ref).max() <= TOL * max(1.0, float(np.abs(ref).max()))


def test_switch_between_reference_and_custom_op():
    assert not tops.use_custom_op()
    with tops.exporting():
        assert tops.use_custom_op()
        with tops.exporting(False):
            assert not tops.use_custom_op()
    assert not tops.use_custom_op()
    # in eager mode the custom-op path computes the same values (no autograd there)
    image, kernel = torch.rand(1, 3, 6, 8), torch.softmax(torch.rand(1, 9, 6, 8), 1)
    with tops.exporting():
        custom = kernel_apply(image, kernel, dilation=2)
    assert not custom.requires_grad
    plain = kernel_apply(image, kernel.requires_grad_(True), dilation=2)
    assert plain.requires_grad
    assert torch.allclose(custom, plain.detach(), atol=1e-6)
    with pytest.raises(ValueError, match="odd"):
        kernel_apply(image, torch.rand(1, 4, 6, 8))
