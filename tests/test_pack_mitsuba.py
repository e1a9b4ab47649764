"""scripts/pack_mitsuba.py: the repacked mitsuba wheel keeps the RGB variants and the plugins
the scene kinds use, drops the rest, and has a RECORD that matches what it holds."""

from __future__ import annotations

import base64
import hashlib
import importlib.util
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("pack_mitsuba", ROOT / "scripts/pack_mitsuba.py")
pack_mitsuba = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(pack_mitsuba)

MEMBERS = {
    "mitsuba/__init__.py": True,
    "mitsuba/__init__.pyi": False,
    "mitsuba/libmitsuba.so": True,
    "mitsuba/libembree3.so": True,
    "mitsuba/scalar_rgb.cpython-312-x86_64-linux-gnu.so": True,
    "mitsuba/llvm_ad_rgb.cpython-312-x86_64-linux-gnu.so": True,
    "mitsuba/cuda_ad_rgb.cpython-312-x86_64-linux-gnu.so": True,
    "mitsuba/cuda_ad_spectral_polarized.cpython-312-x86_64-linux-gnu.so": False,
    "mitsuba/llvm_ad_mono.cpython-312-x86_64-linux-gnu.so": False,
    "mitsuba/scalar_spectral.cpython-312-x86_64-linux-gnu.so": False,
    "mitsuba/mitsuba_ext.cpython-312-x86_64-linux-gnu.so": True,
    "mitsuba/plugins/path.so": True,
    "mitsuba/plugins/thindielectric.so": True,
    "mitsuba/plugins/volpath.so": False,
    "mitsuba/plugins/hair.so": False,
    "mitsuba/data/ior/gold.eta.spd": True,
    "mitsuba/data/srgb.coeff": False,
    "mitsuba/include/mitsuba/core/fwd.h": False,
    "mitsuba-3.9.1.dist-info/METADATA": True,
}


def test_repack_keeps_what_the_renderer_needs(tmp_path):
    wheel = tmp_path / "mitsuba-3.9.1-cp312-cp312-manylinux_2_28_x86_64.whl"
    with zipfile.ZipFile(wheel, "w") as z:
        for name in MEMBERS:
            z.writestr(name, f"contents of {name}")
        z.writestr("mitsuba-3.9.1.dist-info/RECORD", "stale,,\n")
    out = pack_mitsuba.repack(wheel, tmp_path / "packed")
    assert out.name == wheel.name
    with zipfile.ZipFile(out) as z:
        names = set(z.namelist())
        assert names == {n for n, kept in MEMBERS.items() if kept} | {
            "mitsuba-3.9.1.dist-info/RECORD"
        }
        record = z.read("mitsuba-3.9.1.dist-info/RECORD").decode().splitlines()
        rows = dict(line.split(",", 1) for line in record)
        assert rows.pop("mitsuba-3.9.1.dist-info/RECORD") == ","
        assert set(rows) == names - {"mitsuba-3.9.1.dist-info/RECORD"}
        for name, row in rows.items():
            data = z.read(name)
            digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=")
            assert row == f"sha256={digest.decode()},{len(data)}"


def test_cuda_only_pack_drops_the_cpu_variants():
    assert not pack_mitsuba.keep(
        "mitsuba/llvm_ad_rgb.cpython-312-x86_64-linux-gnu.so", variants=("cuda_ad_rgb",)
    )
    assert pack_mitsuba.keep(
        "mitsuba/cuda_ad_rgb.cpython-312-x86_64-linux-gnu.so", variants=("cuda_ad_rgb",)
    )
