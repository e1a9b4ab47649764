"""Render one animated sequence with Mitsuba 3 in the canonical EXR layout.

One folder per sequence:
- `frame_NNNN.exr`: `R,G,B` noisy 1-spp radiance, `colorB.R/G/B` an independent
  1-spp estimate (other seed), `albedo.R/G/B`, `normal.X/Y/Z`, `depth.Z`,
  `motion.X/Y` (conventions in `features.py`);
- with `RenderConfig.samples` = S >= 1: S independent 1-spp samples per pixel, each a
  miniature canonical frame `sample<i>.R/G/B` (radiance), `sample<i>.albedo.R/G/B`,
  `sample<i>.normal.X/Y/Z`, `sample<i>.depth.Z` (runtime/sequences/samples.py), its features
  taken at the sample's own jittered position by the same ray as its radiance (`aov` integrator
  wrapping `path`); then `R,G,B` is the mean of the S samples and `colorB` an independent
  S-spp estimate;
- `ref_NNNN.exr`: `R,G,B` high-spp reference of the same frame;
- `meta.json` (written last, atomically: a sequence without it is incomplete);
- while it renders, `partial.json` (the job's settings, scene and exposure): a killed render
  resumes from it, keeping the frames whose `frame_` and `ref_` files are both complete
  (atomic writes: a file under its final name is whole) and rendering the rest with the same
  seeds; a folder from other settings is cleared and rendered again.

The scene is `kinds.generate_scene(seed, cfg.kinds, cfg.exclude_kinds)`; its `camera` path
spec (paths.py) gives the cameras and the cut frames. At a cut (and at frame 0) the motion
vectors are 0 and meta.json marks the frame (`cuts`, each camera's `reset`): the contract's
`reset = 1`. A description without `camera` (the `legacy` kind) gets the original orbit.

Radiance: `path` integrator, box reconstruction filter, multiplied by one
per-sequence exposure factor (equivalent to scaling every emitter) chosen from
a low-spp pilot of frame 0. Features come from the `aov` integrator at pixel
centres (`stratified` sampler, 1 sample, no jitter).
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..runtime.errors import InputError
from ..runtime.sequences.atomic import write_text_atomic
from ..runtime.sequences.exr import read_exr_header, write_exr
from ..runtime.sequences.samples import DEFAULT_SAMPLE_FEATURES, sample_channels
from .camera import Camera, orbit_path, project
from .features import BACKGROUND_ALBEDO, BACKGROUND_DEPTH, canonical_features, override_albedo
from .kinds import KINDS, generate_scene
from .paths import cameras_from_spec
from .reuse import check_source, copy_reference
from .scene import DIELECTRICS, ID_SCALE, build_scene, conductor_f0, shape_materials
from .seeds import derive_seed

RADIANCE_LIMIT = 65000.0  # keep radiance finite in float16 (runtime.contract.HALF_MAX = 65504)
_AOVS = "albedo:albedo,nn:sh_normal,pp:position"


@dataclass(frozen=True)
class RenderConfig:
    """Settings shared by every sequence of a render job."""

    width: int = 64
    height: int = 64
    frames: int = 8
    spp_ref: int = 1024
    max_depth: int = 6
    half: bool = True
    pilot_spp: int = 16
    samples: int = 0  # S >= 1: write S per-sample layers, color = their mean (S spp)
    kinds: tuple[str, ...] | None = None  # scene kinds to draw from (None: all weighted)
    exclude_kinds: tuple[str, ...] = ()


PARTIAL = "partial.json"
REF_SPP_CAP = 4096  # a kind's ref_spp_scale never raises the reference count above this
MAX_REDRAWS = 8  # shots drawn again (from derived seeds) when one is unusable
NEAR_DEPTH = 0.2  # world units: a view mostly nearer than this is inside or against a shape
NEAR_FRACTION = 0.3
BLACK_LUMINANCE = 1e-5  # mean pilot radiance below this: frame 0 sees no light


def reference_spp(spp_ref: int, kind: str | None) -> int:
    """The reference sample count of a sequence: `spp_ref` times its kind's `ref_spp_scale`
    (kinds whose references converge slowly), never above max(spp_ref, REF_SPP_CAP)."""
    scale = KINDS[kind].ref_spp_scale if kind in KINDS else 1
    return min(spp_ref * scale, max(spp_ref, REF_SPP_CAP))


def shot_problem(mi, mi_scene, aov, cams: list[Camera], pilot: np.ndarray) -> str | None:
    """Why a drawn shot is unusable (None: usable): frame 0 black, or on some frame the
    camera inside or against a shape (a random camera path can enter a prop or a wall)."""
    lum = float(np.mean(pilot))
    if not lum > BLACK_LUMINANCE:
        return f"frame 0 is black (mean pilot radiance {lum:.2g})"
    for t, cam in enumerate(cams):
        pp = _aovs(mi, mi_scene, aov, cam)["pp"].astype(np.float64)
        hit = np.linalg.norm(pp, axis=-1) > 0
        near = float((hit & (project(pp, cam)[2] < NEAR_DEPTH)).mean())
        if near > NEAR_FRACTION:
            return f"frame {t}: {near:.0%} of the view nearer than {NEAR_DEPTH}"
    return None


def write_json_atomic(path: Path, data: dict) -> None:
    """Write JSON atomically (temp file in the same folder, then rename)."""
    write_text_atomic(path, json.dumps(data, indent=1) + "\n")


def _sensor(mi, cam: Camera, sampler: dict):
    return mi.load_dict(
        {
            "type": "perspective",
            "fov": cam.fov,
            "fov_axis": "x",
            "near_clip": 0.01,
            "far_clip": 1.0e5,
            "to_world": mi.ScalarTransform4f().look_at(
                origin=list(cam.origin), target=list(cam.target), up=list(cam.up)
            ),
            "film": {
                "type": "hdrfilm",
                "width": cam.width,
                "height": cam.height,
                "rfilter": {"type": "box"},
                "pixel_format": "rgb",
            },
            "sampler": sampler,
        }
    )


def _radiance(
    mi, scene, integrator, cam: Camera, spp: int, seed: int, sampler: str
) -> tuple[np.ndarray, int]:
    """(H, W, 3) radiance and the sample count actually used (multijitter may round it)."""
    sensor = _sensor(mi, cam, {"type": sampler, "sample_count": spp})
    img = mi.render(scene, sensor=sensor, integrator=integrator, spp=spp, seed=seed)
    return np.array(img, dtype=np.float32)[..., :3], int(sensor.sampler().sample_count())


def _aovs(mi, scene, integrator, cam: Camera, seed: int | None = None) -> dict[str, np.ndarray]:
    """The film's layers after one 1-spp pass: at pixel centres (seed None), else at the
    jittered positions of an `independent` sampler with `seed` (same seed, same rays)."""
    if seed is None:
        sampler = {"type": "stratified", "sample_count": 1, "jitter": False}
    else:
        sampler = {"type": "independent", "sample_count": 1}
    sensor = _sensor(mi, cam, sampler)
    mi.render(scene, sensor=sensor, integrator=integrator, spp=1, seed=seed or 0)
    parts = dict(sensor.film().bitmap(raw=False).split())
    return {k: np.array(v, dtype=np.float32) for k, v in parts.items()}


def sanitize(x: np.ndarray, limit: float | None) -> tuple[np.ndarray, int]:
    """Replace NaN/Inf by 0 and negatives by 0, clamp to `limit`; return (array, #replaced)."""
    bad = ~np.isfinite(x)
    n = int(bad.sum())
    x = np.where(bad, 0.0, np.maximum(x, 0.0))
    if limit is not None:
        x = np.minimum(x, limit)
    return x.astype(np.float32), n


def auto_exposure(pilot: np.ndarray, target: float) -> float:
    """Factor that brings the mean luminance (clipped at its 99th percentile) to `target`."""
    lum = pilot @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    lum = np.minimum(lum, np.percentile(lum, 99.0))
    mean = float(lum.mean())
    return float(np.clip(target / max(mean, 1e-6), 1e-3, 1e3))


def albedo_table(mi, desc: dict) -> np.ndarray:
    """(1 + #shapes, 3) albedo overrides by shape id (NaN: keep): emitters 1, conductors F0."""
    materials = list(shape_materials(desc).values())
    table = np.full((len(materials) + 1, 3), np.nan)
    for i, mat in enumerate(materials):
        if mat is None or mat["type"] in DIELECTRICS:  # emitters, glass and water: 1
            table[i + 1] = 1.0
        elif mat["type"] in ("conductor", "roughconductor"):
            table[i + 1] = conductor_f0(mi, mat["material"])
    return table


def decode_ids(code: np.ndarray) -> np.ndarray:
    """Shape ids (0 = miss) from the red albedo of the id-pass scene."""
    return np.rint(np.nan_to_num(code) * ID_SCALE).astype(np.int64)


def _rgb(prefix: str, img: np.ndarray) -> dict[str, np.ndarray]:
    return {f"{prefix}{c}": img[..., i] for i, c in enumerate("RGB")}


def _sample_layers(
    mi, scenes, integrators, alb_table, cam: Camera, seeds: list[int], exposure: float, limit
) -> tuple[dict[str, np.ndarray], np.ndarray, int]:
    """Per-sample layers of one frame (runtime/sequences/samples.py names), the mean radiance
    and the count of replaced non-finite values. Sample i: one 1-spp pass of `aov` wrapping `path`
    (radiance and features from the same ray) and an id pass with the same seed (same ray)."""
    mi_scene, id_scene = scenes
    aov_path, aov_id = integrators
    layers: dict[str, np.ndarray] = {}
    total = None
    replaced = 0
    for i, seed in enumerate(seeds):
        a = _aovs(mi, mi_scene, aov_path, cam, seed)
        radiance, n = sanitize(a["<root>"][..., :3] * exposure, limit)
        replaced += n
        total = radiance if total is None else total + radiance
        ids = decode_ids(_aovs(mi, id_scene, aov_id, cam, seed)["id"][..., 0])
        albedo = override_albedo(a["albedo"], ids, alb_table)
        feats = canonical_features(albedo, a["nn"], a["pp"], ids > 0, cam, None)
        per_feature = {
            "color": [radiance[..., c] for c in range(3)],
            "albedo": [feats[f"albedo.{c}"] for c in "RGB"],
            "normal": [feats[f"normal.{c}"] for c in "XYZ"],
            "depth": [feats["depth.Z"]],
        }
        for feature in DEFAULT_SAMPLE_FEATURES:
            for name, plane in zip(sample_channels(i, feature), per_feature[feature], strict=True):
                layers[name] = plane
    return layers, total / len(seeds), replaced


def _complete_frames(out: Path, frames: int) -> set[int]:
    """Frames whose `frame_` and `ref_` files are both whole (readable EXR headers)."""
    done = set()
    for t in range(frames):
        try:
            read_exr_header(out / f"frame_{t:04d}.exr")
            read_exr_header(out / f"ref_{t:04d}.exr")
        except Exception:  # missing or unreadable: render it again
            continue
        done.add(t)
    return done


def _clear(out: Path, keep: set[int]) -> None:
    """Remove meta.json, the frames not in `keep` and temp files a killed write left."""
    (out / "meta.json").unlink(missing_ok=True)
    for p in [*out.glob("frame_*.exr"), *out.glob("ref_*.exr")]:
        try:
            t = int(p.stem.split("_")[1])
        except ValueError:
            t = -1
        if t not in keep:
            p.unlink(missing_ok=True)
    # runtime/sequences/atomic.py temp files: .<stem>.<8 chars>.tmp<ext>
    for p in out.glob(".*.tmp.*"):
        p.unlink(missing_ok=True)


def _resume_point(out: Path, job: dict, frames: int) -> tuple[set[int], float | None]:
    """Frames to keep and the exposure to reuse, from `partial.json` when it describes `job`."""
    try:
        partial = json.loads((out / PARTIAL).read_text())
    except (OSError, ValueError):
        return set(), None
    if partial.get("job") != job:
        return set(), None
    return _complete_frames(out, frames), float(partial["exposure"])


def render_sequence(
    out_dir: str | os.PathLike,
    scene_seed: int,
    cfg: RenderConfig,
    *,
    variant: str,
    on_frame: Callable[[int], None] | None = None,
    scene: dict | None = None,
    cameras: list[Camera] | None = None,
    cuts: list[int] | None = None,
    meta_extra: dict | None = None,
    references_from: str | os.PathLike | None = None,
) -> dict:
    """Render one sequence into `out_dir` (created), resuming a killed render of the same job;
    return its meta.json content.

    `references_from`: a complete sequence rendered from the same shots (seed, scene,
    cameras, renderer, reference spp, exposure; datagen/reuse.py checks) whose `ref_` files
    are copied instead of rendered, e.g. a set rendered again with `samples`.

    The Mitsuba variant must already be set (see `variant.select_variant`). `scene`
    (a `generate_scene`-style description) and `cameras` (with their `cuts`) override the ones
    drawn from `scene_seed` (for tests and hand-made shots); `meta_extra` is merged into
    meta.json. `on_frame(t)` is called for every frame, kept ones included.
    """
    import mitsuba as mi

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    path = mi.load_dict({"type": "path", "max_depth": cfg.max_depth})
    aov = mi.load_dict({"type": "aov", "aovs": _AOVS})
    pilot_seed = derive_seed(scene_seed, 2)
    redraws: list[dict] = []
    draw_seed = scene_seed
    for attempt in range(MAX_REDRAWS + 1):
        if scene is not None:
            desc = scene
        else:
            desc = generate_scene(draw_seed, cfg.kinds, cfg.exclude_kinds)
        rng = np.random.default_rng(derive_seed(draw_seed, 1))
        cams = orbit_path(rng, cfg.frames, cfg.width, cfg.height)  # legacy; draws rng as before
        cut_list: list[int] = []
        if "camera" in desc:
            cams, cut_list = cameras_from_spec(desc["camera"], cfg.frames, cfg.width, cfg.height)
        if cameras is not None:
            cams, cut_list = list(cameras), sorted(cuts or [])
        target = float(rng.uniform(0.25, 0.6))
        mi_scene = build_scene(desc)
        pilot, _ = _radiance(mi, mi_scene, path, cams[0], cfg.pilot_spp, pilot_seed, "independent")
        pilot = np.nan_to_num(pilot, nan=0.0, posinf=0.0, neginf=0.0)
        why = None if scene is not None else shot_problem(mi, mi_scene, aov, cams, pilot)
        if why is None:
            break
        redraws.append({"scene_seed": int(draw_seed), "kind": desc.get("kind"), "why": why})
        draw_seed = derive_seed(scene_seed, 3, attempt)
    else:
        raise RuntimeError(f"{out}: no usable shot in {MAX_REDRAWS + 1} draws: {redraws}")
    job = json.loads(json.dumps({
        "config": asdict(cfg), "scene_seed": int(scene_seed), "variant": variant,
        "mitsuba": mi.__version__, "scene": desc, "cuts": cut_list,
        "spp_ref": reference_spp(cfg.spp_ref, desc.get("kind")),
        "cameras": [c.to_json() for c in cams],
    }))  # fmt: skip
    keep, exposure = _resume_point(out, job, len(cams))
    _clear(out, keep)

    id_scene = build_scene(desc, id_pass=True)
    alb_table = albedo_table(mi, desc)
    aov_id = mi.load_dict({"type": "aov", "aovs": "id:albedo"})
    aov_path = mi.load_dict(
        {"type": "aov", "aovs": _AOVS, "integrator": {"type": "path", "max_depth": cfg.max_depth}}
    )
    spp = max(1, cfg.samples)

    started = exposure is not None
    spp_ref = requested_ref = reference_spp(cfg.spp_ref, desc.get("kind"))
    source = None if references_from is None else Path(references_from)
    if source is not None:  # before anything is written; the references' exposure is ours
        storage = "float16" if cfg.half else "float32"
        spp_ref = _multijitter_count(mi, requested_ref)  # what the copied references hold
        lent = check_source(source, job, ref_spp=spp_ref, storage=storage)["exposure"]
        if started and exposure != lent:
            raise InputError(
                f"{out}: rendered so far with exposure {exposure}, its references' source "
                f"{source} has {lent}: render it again with --overwrite"
            )
        exposure = float(lent)
    if exposure is None:
        exposure = auto_exposure(pilot, target)
    if not started:
        write_json_atomic(out / PARTIAL, {"job": job, "exposure": exposure})
    limit = RADIANCE_LIMIT if cfg.half else None
    replaced = 0
    seeds = []
    for t, cam in enumerate(cams):
        s_a, s_b, s_ref = (derive_seed(scene_seed, 100 + t, k) for k in range(3))
        seeds.append({"color": s_a, "colorB": s_b, "ref": s_ref})
        sample_seeds = [derive_seed(scene_seed, 100 + t, 10 + i) for i in range(cfg.samples)]
        if cfg.samples:
            seeds[-1]["samples"] = sample_seeds
        if t in keep:
            if on_frame is not None:
                on_frame(t)
            continue
        sample_layers: dict[str, np.ndarray] = {}
        if cfg.samples:  # color = the mean of S 1-spp samples, each written as layers
            sample_layers, noisy, n = _sample_layers(
                mi, (mi_scene, id_scene), (aov_path, aov_id), alb_table, cam, sample_seeds,
                exposure, limit,
            )  # fmt: skip
            replaced += n
            imgs = []
        else:
            imgs = [_radiance(mi, mi_scene, path, cam, 1, s_a, "independent")[0]]
        imgs.append(_radiance(mi, mi_scene, path, cam, spp, s_b, "independent")[0])
        if source is None:
            ref_img, spp_ref = _radiance(
                mi, mi_scene, path, cam, requested_ref, s_ref, "multijitter"
            )
            imgs.append(ref_img)
        clean = []
        for img in imgs:
            x, n = sanitize(img * exposure, limit)
            replaced += n
            clean.append(x)
        ref = clean.pop() if source is None else None
        if cfg.samples:
            (noisy_b,) = clean
        else:
            noisy, noisy_b = clean
        a = _aovs(mi, mi_scene, aov, cam)
        ids = decode_ids(_aovs(mi, id_scene, aov_id, cam)["id"][..., 0])
        hit = ids > 0
        albedo = override_albedo(a["albedo"], ids, alb_table)
        prev = cams[t - 1] if t > 0 and t not in cut_list else None  # a cut: no previous frame
        feats = canonical_features(albedo, a["nn"], a["pp"], hit, cam, prev)
        channels = {**_rgb("", noisy), **_rgb("colorB.", noisy_b), **feats, **sample_layers}
        write_exr(out / f"frame_{t:04d}.exr", channels, half=cfg.half)
        if ref is None:
            copy_reference(source / f"ref_{t:04d}.exr", out / f"ref_{t:04d}.exr")
        else:
            write_exr(out / f"ref_{t:04d}.exr", _rgb("", ref), half=cfg.half)
        if on_frame is not None:
            on_frame(t)
    if keep and spp_ref == requested_ref:  # every frame kept: the sampler's count, as rendered
        spp_ref = _multijitter_count(mi, requested_ref)
    if replaced:
        warnings.warn(
            f"{out}: replaced {replaced} NaN/Inf radiance values with 0", RuntimeWarning, 2
        )
    resets = [t == 0 or t in cut_list for t in range(len(cams))]
    meta = {
        "format": "rtdenoise-sequence-1",
        "scene_seed": int(scene_seed),
        "kind": desc.get("kind", "custom"),
        "frame_count": len(cams),
        "resolution": [cfg.width, cfg.height],
        "cuts": cut_list,
        "spp": {"color": spp, "colorB": spp, "ref": spp_ref, "exposure_pilot": cfg.pilot_spp},
        "samples": cfg.samples,
        "storage": "float16" if cfg.half else "float32",
        "renderer": {
            "name": "mitsuba",
            "version": mi.__version__,
            "variant": variant,
            "integrator": {"type": "path", "max_depth": cfg.max_depth},
            "rfilter": "box",
            "samplers": {"color": "independent", "ref": "multijitter", "features": "stratified"},
        },
        "exposure": exposure,
        "nonfinite_replaced": replaced,
        "resumed_frames": sorted(keep),
        **({"references_from": str(source)} if source is not None else {}),
        "redraws": redraws,
        "seeds": seeds,
        "cameras": [
            {
                "frame": t,
                "reset": resets[t],
                **{k: v for k, v in c.to_json().items() if k not in ("width", "height")},
            }
            for t, c in enumerate(cams)
        ],  # fmt: skip
        "camera_model": "pinhole, fov in degrees along x (Mitsuba perspective, fov_axis=x)",
        "conventions": {
            "color": f"linear HDR radiance, {spp} spp, times `exposure`; colorB: independent "
            "seed" + ("; color is the mean of the sample layers" if cfg.samples else ""),
            "samples": "sample<i>.R/G/B radiance (times `exposure`), sample<i>.albedo / .normal / "
            ".depth as the pixel buffers, at the sample's own jittered position",
            "albedo": "aov albedo clamped to [0, 1]; conductors: RGB reflectance at normal "
            f"incidence; emitters and dielectrics 1; background {BACKGROUND_ALBEDO}",
            "normal": "camera space, x right, y up, z towards the camera, unit, facing the "
            "camera; background 0",
            "depth": f"planar view depth (world units); background {BACKGROUND_DEPTH}",
            "motion": "pixels, previous position = current + motion, x right, y down; "
            "background: environment direction seen by the previous camera; frame 0 and "
            "cut frames: 0",
            "cuts": "frames where a new shot begins: the camera jumps, the history must be "
            "reset (contract: reset = 1; cameras[t].reset is true at frame 0 and at cuts)",
            "pixel_centres": "+0.5; features sampled at pixel centres, radiance box-filtered",
        },
        "scene": desc,
        **(meta_extra or {}),
    }
    write_json_atomic(out / "meta.json", meta)
    (out / PARTIAL).unlink(missing_ok=True)
    return meta


def _multijitter_count(mi, spp: int) -> int:
    """The sample count a `multijitter` sampler uses for a requested `spp`."""
    return int(mi.load_dict({"type": "multijitter", "sample_count": spp}).sample_count())
