"""What made an output: the model, the options and the rtdenoise version, in its EXR header.

`denoise-run` writes these string attributes into every output file (`record`):

- `rtdenoise.model`: the model, the .onnx path it loaded (a `demo:` model's file in the
  package), or `none`;
- `rtdenoise.model_sha256`: sha256 of that file (empty for `none` or a model given as bytes);
- `rtdenoise.options`: a JSON object of the options that change the pixels: the layout (its
  name and its file's sha256), the `--channel` overrides, half or float output, the model's
  run-time options (`--kernel-size`, ...) and, for a model that learns online, `learn`,
  `learn_every` and `relearn_at_cuts`;
- `rtdenoise.version`: the rtdenoise version that wrote it.

`--resume` keeps an output only when its model (by sha256) and options equal this run's
(`mismatch`); the version is recorded, not compared (a newer rtdenoise continues an older run).
How the frames are computed (threads, providers, fast kernels or the portable bodies, which
agree within 1e-5) is not an option here.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rtdenoise._version import __version__

from .layouts import Layout, layout_fingerprint

MODEL = "rtdenoise.model"
MODEL_SHA256 = "rtdenoise.model_sha256"
OPTIONS = "rtdenoise.options"
VERSION = "rtdenoise.version"
KEYS = (MODEL, MODEL_SHA256, OPTIONS, VERSION)


def file_sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def model_of(backend: Any) -> tuple[str, str]:
    """(name, sha256) of the backend's model: a Denoiser's file, `none` for the pass-through."""
    source = getattr(backend, "source", None)
    if source is None:
        return str(getattr(backend, "name", type(backend).__name__)), ""
    path = Path(source)
    return str(source), file_sha256(path) if path.is_file() else ""


def options_of(
    backend: Any, layout: Layout, overrides: Mapping[str, str], half: bool
) -> dict[str, Any]:
    """The options of a run that change its output pixels (see the module docstring)."""
    options: dict[str, Any] = {
        "layout": layout_fingerprint(layout),
        "channels": dict(sorted(overrides.items())),
        "half": bool(half),
    }
    model_options = getattr(backend, "options", None)
    if model_options:
        options["model_options"] = {k: float(v) for k, v in sorted(dict(model_options).items())}
    if getattr(backend, "online", None):
        options["learn"] = bool(backend.learn)
        options["learn_every"] = int(backend.learn_every)
        options["relearn_at_cuts"] = bool(backend.relearn_at_cuts)
    return options


def record(
    backend: Any, layout: Layout, overrides: Mapping[str, str], half: bool
) -> dict[str, str]:
    """The header attributes of an output of this run."""
    name, sha = model_of(backend)
    options = json.dumps(options_of(backend, layout, overrides, half), sort_keys=True)
    return {MODEL: name, MODEL_SHA256: sha, OPTIONS: options, VERSION: __version__}


def mismatch(recorded: Mapping[str, str], current: Mapping[str, str]) -> str | None:
    """What differs between an existing output's record and this run's, for a message
    (None: the same model and options)."""
    if MODEL_SHA256 not in recorded or OPTIONS not in recorded:
        return "it records no model or options (written by another program or an older run)"
    if recorded[MODEL_SHA256] != current[MODEL_SHA256]:
        return (
            f"model differs: {recorded.get(MODEL, '?')} (sha256 {recorded[MODEL_SHA256][:12]}) "
            f"there, {current[MODEL]} (sha256 {current[MODEL_SHA256][:12]}) now"
        )
    try:
        there = json.loads(recorded[OPTIONS])
    except ValueError:
        return f"its {OPTIONS} attribute is not JSON"
    here = json.loads(current[OPTIONS])
    if not isinstance(there, dict):
        return f"its {OPTIONS} attribute is not a JSON object"
    differ = [k for k in sorted(set(there) | set(here)) if there.get(k) != here.get(k)]
    if differ:
        return "options differ: " + ", ".join(
            f"{k} {json.dumps(there.get(k))} there, {json.dumps(here.get(k))} now" for k in differ
        )
    return None


__all__ = ["KEYS", "MODEL", "MODEL_SHA256", "OPTIONS", "VERSION", "mismatch", "record"]
