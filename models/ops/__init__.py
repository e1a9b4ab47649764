"""Filter stages in torch form: one module per op (named like its spec in rtdenoise.ops).

Importing this package imports every module, which registers each op's `TorchOp` (and its
`torch.ops.rtdenoise.*` custom op) in `TORCH_OPS`; models import the public functions from
the op modules. See docs/architecture.md, "Adding an op".
"""

from rtdenoise.ops import import_submodules, plugins

from .export_mode import exporting, use_custom_op
from .torch_op import TORCH_OPS, TorchOp, observe_calls, torch_op

import_submodules(__name__)
plugins.load_modules(plugins.TORCH_FORMS)  # forms of other packages' ops (docs/your-own-model.md)

__all__ = ["TORCH_OPS", "TorchOp", "exporting", "observe_calls", "torch_op", "use_custom_op"]
