"""Filter stages in torch form (design.md s.2): one module per op, one public function each.

Importing this package registers every `torch.ops.rtdenoise.*` custom op used at export.
Adding an op: a new module here, and one line in `OPS` below.
"""

from .adaptive_fusion import adaptive_fusion, adaptive_fusion_op, adaptive_fusion_reference
from .kernel_apply import kernel_apply, kernel_apply_op, kernel_apply_reference
from .kernel_fusion import kernel_fusion, kernel_fusion_op, kernel_fusion_reference
from .registry import NAMESPACE, exporting, use_custom_op
from .weight_sharing_filter import (
    weight_sharing_filter,
    weight_sharing_filter_op,
    weight_sharing_filter_reference,
)

# ONNX op name -> (public function, torch custom op, reference implementation).
OPS = {
    "KernelApply": (kernel_apply, kernel_apply_op, kernel_apply_reference),
    "AdaptiveFusion": (adaptive_fusion, adaptive_fusion_op, adaptive_fusion_reference),
    "WeightSharingFilter": (
        weight_sharing_filter,
        weight_sharing_filter_op,
        weight_sharing_filter_reference,
    ),
    "KernelFusion": (kernel_fusion, kernel_fusion_op, kernel_fusion_reference),
}

__all__ = [
    "NAMESPACE",
    "OPS",
    "adaptive_fusion",
    "adaptive_fusion_op",
    "adaptive_fusion_reference",
    "exporting",
    "kernel_apply",
    "kernel_apply_op",
    "kernel_apply_reference",
    "kernel_fusion",
    "kernel_fusion_op",
    "kernel_fusion_reference",
    "use_custom_op",
    "weight_sharing_filter",
    "weight_sharing_filter_op",
    "weight_sharing_filter_reference",
]
