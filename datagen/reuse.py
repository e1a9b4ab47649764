"""References reused from a sequence already rendered: the same shots, other inputs.

A reference is most of a sequence's render time (256-4096 spp against the input's 1-2), and
it depends only on the scene, the cameras, the reference seed of each frame, the sample count,
the exposure and the renderer: not on how the noisy input is rendered. So a set rendered
again with other input settings (e.g. `--samples 2` for a per-sample model) can take the
references of a complete set rendered from the same seeds instead of rendering them again,
bit for bit what it would have rendered (same variant, same seeds). `check_source` refuses a
source whose shots differ, naming what differs.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from ..runtime.errors import InputError
from ..runtime.sequences.atomic import atomic_path

_CAMERA_ONLY_META = ("frame", "reset")  # meta.json camera fields the job's cameras lack
_CAMERA_ONLY_JOB = ("width", "height")  # and the other way round


def check_source(folder: Path, job: dict, *, ref_spp: int, storage: str) -> dict:
    """The meta.json of `folder` if its references are this render's: InputError naming the
    first field that differs (scene, cameras, cuts, resolution, renderer, spp, storage). The
    exposure is not compared: the render takes the source's (`meta["exposure"]`), since the
    references were scaled by it (a pilot render can differ in its last digits between runs)."""
    meta_path = folder / "meta.json"
    if not meta_path.is_file():
        raise InputError(f"{folder}: no meta.json, not a complete sequence: no references to reuse")
    meta = json.loads(meta_path.read_text())
    cfg = job["config"]
    theirs_cams = [
        {k: v for k, v in c.items() if k not in _CAMERA_ONLY_META} for c in meta["cameras"]
    ]
    ours_cams = [{k: v for k, v in c.items() if k not in _CAMERA_ONLY_JOB} for c in job["cameras"]]
    renderer = meta.get("renderer", {})
    fields = {
        "scene": (meta.get("scene"), job["scene"]),
        "cameras": (theirs_cams, ours_cams),
        "cuts": (meta.get("cuts"), job["cuts"]),
        "resolution": (meta.get("resolution"), [cfg["width"], cfg["height"]]),
        "variant": (renderer.get("variant"), job["variant"]),
        "max_depth": (renderer.get("integrator", {}).get("max_depth"), cfg["max_depth"]),
        "reference spp": (meta.get("spp", {}).get("ref"), ref_spp),
        "storage": (meta.get("storage"), storage),
    }
    for name, (theirs, ours) in fields.items():
        if theirs != ours:
            shown = (theirs, ours) if name not in ("scene", "cameras") else ("...", "...")
            raise InputError(
                f"{folder}: its {name} differs from this render's ({shown[0]!r} against "
                f"{shown[1]!r}): its references are not this sequence's"
            )
    return meta


def copy_reference(source: Path, target: Path) -> None:
    """Copy one reference file atomically (a temp file beside `target`, then a rename)."""
    with atomic_path(target) as tmp:
        shutil.copyfile(source, tmp)


__all__ = ["check_source", "copy_reference"]
