"""Deploy-mode conversion: one generic reparameterisation pass over any model.

Every module that can fold itself (RepVGG branches, BatchNorm into the preceding
conv, ...) implements `reparameterize(self) -> nn.Module | None`, returning its
single-branch replacement (or None after folding in place). `to_deploy` walks the
model bottom-up and swaps each such module for its replacement, in the spirit of
timm's `reparameterize_model`.
"""

from __future__ import annotations

import copy

from torch import nn


def to_deploy(model: nn.Module, *, inplace: bool = False) -> nn.Module:
    """Return `model` in deploy form (eval mode, every foldable module folded)."""
    if not inplace:
        model = copy.deepcopy(model)
    model.eval()
    _fold_children(model)
    return model


def _fold_children(parent: nn.Module) -> None:
    for name, child in list(parent.named_children()):
        _fold_children(child)
        fold = getattr(child, "reparameterize", None)
        if callable(fold):
            replacement = fold()
            if replacement is not None:
                setattr(parent, name, replacement)
