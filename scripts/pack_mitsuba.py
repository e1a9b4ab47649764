"""Repack a mitsuba wheel with only what denoise-render needs, for a size-limited transfer.

The PyPI wheel (about 63 MB) holds 15 variants, 100 plugins, C++ headers and the spectral
upsampling table; the data engine renders RGB only (scalar_rgb, llvm_ad_rgb, cuda_ad_rgb) with
the plugins its scene kinds use (datagen/kinds.py, datagen/scene.py, datagen/render.py). The
plugin list is the set a render of every kind loaded (read from /proc/self/maps after
`denoise-render -n 40 --seed 555`, every kind drawn, llvm_ad_rgb); a scene kind that starts using
a new plugin must add it here (the repacked wheel then fails with Mitsuba's "Plugin ... not
found", naming it). RECORD is rewritten for the files kept, so pip installs it like any wheel.

    python scripts/pack_mitsuba.py mitsuba-3.9.1-cp312-...whl -o packed/
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import re
import zipfile
from pathlib import Path

VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
PLUGINS = frozenset(
    "aov area bitmap box checkerboard conductor constant cube cylinder d65 dielectric diffuse "
    "disk envmap hdrfilm independent merge multijitter path perspective plastic rectangle "
    "regular roughconductor roughdielectric roughplastic sphere srgb stratified thindielectric "
    "twosided uniform".split()
)
# C++ headers, CMake and pkg-config files, typing stubs, the spectral variants' upsampling
# table and the sun-sky datasets (the kinds' skies are procedural bitmaps)
DROPPED_PREFIXES = (
    "mitsuba/include/",
    "mitsuba/cmake/",
    "mitsuba/pkgconfig/",
    "mitsuba/mitsuba_stubs/",
    "mitsuba/data/srgb.coeff",
    "mitsuba/data/sunsky/",
)
_VARIANT_MODULE = re.compile(r"^mitsuba/((?:scalar|llvm_ad|cuda_ad)_\w+?)\.cpython-.*\.so$")
_PLUGIN = re.compile(r"^mitsuba/plugins/(\w+)\.so$")


def keep(name: str, variants: tuple[str, ...] = VARIANTS) -> bool:
    """Whether the wheel member `name` is needed by denoise-render with `variants`."""
    if name.startswith(DROPPED_PREFIXES) or name.endswith(".pyi"):
        return False
    if m := _VARIANT_MODULE.match(name):
        return m.group(1) in variants
    if m := _PLUGIN.match(name):
        return m.group(1) in PLUGINS
    return True


def _record_line(name: str, data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def repack(wheel: Path, out_dir: Path, variants: tuple[str, ...] = VARIANTS) -> Path:
    """Write `out_dir/<same name>` holding only the members `keep` allows; return its path."""
    out_dir.mkdir(parents=True, exist_ok=True)
    target = out_dir / wheel.name
    tmp = target.with_suffix(".tmp")
    with zipfile.ZipFile(wheel) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        record_name = next(n for n in src.namelist() if n.endswith(".dist-info/RECORD"))
        lines = []
        for info in src.infolist():
            if info.filename == record_name or not keep(info.filename, variants):
                continue
            data = src.read(info)
            dst.writestr(info, data, compress_type=zipfile.ZIP_DEFLATED, compresslevel=9)
            lines.append(_record_line(info.filename, data))
        lines.append(f"{record_name},,")
        dst.writestr(record_name, "\n".join(lines) + "\n")
    tmp.replace(target)
    return target


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("wheel", type=Path)
    ap.add_argument("-o", "--out", type=Path, required=True, help="folder for the repacked wheel")
    ap.add_argument("--variants", default=",".join(VARIANTS), help="variants to keep")
    args = ap.parse_args()
    target = repack(args.wheel, args.out, tuple(args.variants.split(",")))
    mb = 1 / 2**20
    print(f"{target}: {args.wheel.stat().st_size * mb:.1f} MiB -> {target.stat().st_size * mb:.1f}")


if __name__ == "__main__":
    main()
