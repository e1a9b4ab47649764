"""Channel layouts: canonical, blender (Cycles multilayer, multi-part) and --channel overrides."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from rtdenoise.runtime.errors import InputError
from rtdenoise.runtime.sequences.frames import read_frame
from rtdenoise.runtime.sequences.layouts import (
    check_channels,
    extract_buffers,
    get_layout,
    load_layout,
    parse_overrides,
    resolve_channels,
    stack_buffers,
)

H, W = 6, 8


def _chan(value: float) -> np.ndarray:
    return np.full((H, W), value, np.float32)


def blender_channels(prefix: str = "ViewLayer.") -> dict[str, np.ndarray]:
    """Cycles pass names with distinct constant values per channel."""
    ch = {}
    for i, c in enumerate("RGBA"):
        ch[f"{prefix}Combined.{c}"] = _chan(10 + i)
    for i, c in enumerate("RGB"):
        ch[f"{prefix}Noisy Image.{c}"] = _chan(20 + i)
        ch[f"{prefix}Denoising Albedo.{c}"] = _chan([0.5, 3.0, -0.2][i])
    for i, c in enumerate("XYZ"):
        ch[f"{prefix}Denoising Normal.{c}"] = _chan([0.1, 0.2, -0.97][i])
    ch[f"{prefix}Denoising Depth.Z"] = _chan(7.5)
    ch[f"{prefix}Depth.Z"] = _chan(1e10)
    for i, c in enumerate("XYZW"):
        ch[f"{prefix}Vector.{c}"] = _chan([1.5, 2.0, -4.0, 9.0][i])
    return ch


def _check_blender(buffers: dict[str, np.ndarray]) -> None:
    assert {k: v.shape[0] for k, v in buffers.items()} == {
        "color": 3,
        "albedo": 3,
        "normal": 3,
        "depth": 1,
        "motion": 2,
    }
    np.testing.assert_array_equal(buffers["color"][:, 0, 0], [20, 21, 22])  # Noisy Image first
    np.testing.assert_allclose(buffers["albedo"][:, 0, 0], [0.5, 1.0, 0.0])  # clamped to [0,1]
    np.testing.assert_allclose(buffers["normal"][:, 0, 0], [0.1, 0.2, -0.97], rtol=1e-6)
    assert buffers["depth"][0, 0, 0] == 7.5  # Denoising Depth, not planar Depth
    # previous = current + (Vector.X, -Vector.Y)
    np.testing.assert_array_equal(buffers["motion"][:, 0, 0], [1.5, -2.0])


def _write_single(path: Path, channels: dict[str, np.ndarray]) -> Path:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(str(path))
    return path


def _write_multipart(path: Path, channels: dict[str, np.ndarray]) -> Path:
    """One part per pass, named like Blender 5 does ("ViewLayer.Vector")."""
    groups: dict[str, dict[str, np.ndarray]] = {}
    for name, a in channels.items():
        groups.setdefault(name.rsplit(".", 1)[0], {})[name] = a
    parts = [
        OpenEXR.Part(
            {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, ch, name=n
        )
        for n, ch in groups.items()
    ]  # a fresh header per part: OpenEXR.Part stores the part name in it
    OpenEXR.File(parts).write(str(path))
    return path


def test_blender_single_part(tmp_path):
    path = _write_single(tmp_path / "render_0003.exr", blender_channels())
    frame = read_frame(path, "blender")
    assert frame.index == 3
    _check_blender(frame.buffers)


def test_blender_multi_part(tmp_path):
    path = _write_multipart(tmp_path / "render_0004.exr", blender_channels("RenderLayer."))
    with OpenEXR.File(str(path), separate_channels=True) as f:
        assert len(f.parts) == 7  # really multi-part: one part per pass
    _check_blender(read_frame(path, "blender").buffers)


def test_blender_combined_fallback_and_no_prefix():
    ch = {k: v for k, v in blender_channels("").items() if "Noisy" not in k}
    buffers = get_layout("blender").convert(extract_buffers(ch, "blender"))
    np.testing.assert_array_equal(buffers["color"][:, 0, 0], [10, 11, 12])


def test_two_view_layers_are_ambiguous_until_named():
    ch = blender_channels("A.") | blender_channels("B.")
    with pytest.raises(InputError, match=r"f\.exr: layer 'Noisy Image' is ambiguous: A\.Noisy"):
        resolve_channels(ch, "blender", source="f.exr")
    names = {"color": "B.Noisy Image", "albedo": "B.Denoising Albedo", "normal": "none"}
    names |= {"depth": "B.Denoising Depth", "motion": "B.Vector"}
    got = resolve_channels(ch, "blender", names)
    assert got["color"] == ["B.Noisy Image.R", "B.Noisy Image.G", "B.Noisy Image.B"]
    assert got["depth"] == ["B.Denoising Depth.Z"] and got["motion"] == ["B.Vector.X", "B.Vector.Y"]
    assert "normal" not in got


def test_overrides_layer_xyz_single_and_list():
    ch = {c: _chan(1) for c in "RGB"}
    ch |= {f"My.Alb.{c}": _chan(i) for i, c in enumerate("XYZ")}
    ch |= {"zbuf": _chan(4), "mv.U": _chan(5), "mv.V": _chan(6), "albedo.R": _chan(9)}
    ov = parse_overrides(["albedo=My.Alb", "depth=zbuf", "motion = mv.U, mv.V"])
    assert ov == {"albedo": "My.Alb", "depth": "zbuf", "motion": "mv.U, mv.V"}
    got = resolve_channels(ch, "canonical", ov)
    assert got == {
        "color": ["R", "G", "B"],
        "albedo": ["My.Alb.X", "My.Alb.Y", "My.Alb.Z"],
        "depth": ["zbuf"],
        "motion": ["mv.U", "mv.V"],
    }
    buffers = extract_buffers(ch, "canonical", {"motion": "mv", "albedo": "none"})  # -> U,V
    np.testing.assert_array_equal(buffers["motion"][:, 0, 0], [5, 6])
    # a partial canonical layer (albedo.R only) is an error unless overridden or dropped
    with pytest.raises(
        InputError, match=r"missing channel albedo\.G, albedo\.B for buffer 'albedo'"
    ):
        resolve_channels(ch, "canonical")
    assert "albedo" not in resolve_channels(ch, "canonical", {"albedo": "none"})


def test_overridden_buffer_is_required():
    ch = {c: _chan(1) for c in "RGB"}
    with pytest.raises(InputError, match=r"x\.exr: missing channel Alb\.R, Alb\.G, Alb\.B"):
        resolve_channels(ch, "canonical", {"albedo": "Alb"}, source="x.exr")
    with pytest.raises(InputError, match=r"missing channel q\.Y for buffer 'motion'"):
        resolve_channels(ch | {"q.X": _chan(0)}, "canonical", {"motion": "q.X,q.Y"})


def test_missing_color_names_file_channel_and_present():
    ch = {"R": _chan(1), "G": _chan(1), "albedo.R": _chan(0)}
    with pytest.raises(InputError) as info:
        resolve_channels(ch, "canonical", source="shot/f_0001.exr")
    msg = str(info.value)
    assert msg.startswith("shot/f_0001.exr: missing channel B for buffer 'color'")
    assert "channels present: G, R, albedo.R" in msg and "\n" not in msg


@pytest.mark.parametrize(
    "item, match",
    [
        ("albedo", "expected BUFFER=CHANNELS"),
        ("=x", "expected BUFFER=CHANNELS"),
        ("albedo=", "expected BUFFER=CHANNELS"),
        ("diffuse=x", "unknown buffer 'diffuse'"),
        ("motion=a.X,a.Y,a.Z", "motion needs 2 channel names"),
    ],
)
def test_bad_override_syntax(item, match):
    with pytest.raises(InputError, match=match):
        parse_overrides([item])


def test_unknown_layout_and_size_mismatch():
    with pytest.raises(
        InputError, match="unknown layout 'arnold'; known layouts: canonical, blender"
    ):
        get_layout("arnold")
    ch = {"R": _chan(1), "G": _chan(1), "B": np.ones((3, 3), np.float32)}
    with pytest.raises(InputError, match="channel 'B' is 3x3 but channel 'R' is 8x6"):
        extract_buffers(ch, "canonical")


def test_resolve_only_the_buffers_asked_for():
    ch = {c: _chan(1) for c in "RGB"} | {"albedo.R": _chan(0), "depth.Z": _chan(2)}
    with pytest.raises(InputError, match="missing channel albedo.G, albedo.B"):
        resolve_channels(ch, "canonical")  # a partial layer fails the file...
    # ...unless nobody reads it; color is always resolved, overridden buffers too
    assert resolve_channels(ch, "canonical", buffers=()) == {"color": ["R", "G", "B"]}
    got = resolve_channels(ch, "canonical", {"motion": "depth.Z,R"}, buffers=("depth",))
    assert got == {"color": ["R", "G", "B"], "depth": ["depth.Z"], "motion": ["depth.Z", "R"]}
    with pytest.raises(
        InputError, match=r"f\.exr: missing channel normal\.R, normal\.G, normal\.B"
    ):
        resolve_channels(ch, "canonical", source="f.exr", buffers=("normal",), required=("normal",))
    assert "normal" not in resolve_channels(ch, "canonical", buffers=("normal",))  # optional


def test_stack_buffers_converts_once_and_check_channels():
    ch = {c: np.full((H, W), i, np.float16) for i, c in enumerate("RGB")} | {"d": _chan(3)}
    buffers = stack_buffers(ch, {"color": ["R", "G", "B"], "depth": ["d"]})
    assert {k: (v.dtype, v.shape) for k, v in buffers.items()} == {
        "color": (np.float32, (3, H, W)),
        "depth": (np.float32, (1, H, W)),
    }
    np.testing.assert_array_equal(buffers["color"][:, 0, 0], [0, 1, 2])
    layout = get_layout("canonical")
    check_channels(ch, {"color": ["R", "G", "B"]}, layout, source="b.exr")
    with pytest.raises(InputError, match=r"b\.exr: missing channel B, Q for buffer 'color'"):
        check_channels({"R": 0, "G": 0}, {"color": ["R", "B", "Q"]}, layout, source="b.exr")


def test_presets_are_the_shipped_toml_files(tmp_path):
    """`canonical` and `blender` are data; a copy of a preset read by path is the same layout."""
    from rtdenoise.runtime.sequences.layouts import LAYOUTS, load_layout
    from rtdenoise.shipped import LAYOUTS_DIR

    assert list(LAYOUTS) == ["canonical", "blender"]
    assert {lay.path for lay in LAYOUTS.values()} == set(LAYOUTS_DIR.glob("*.toml"))
    copy = tmp_path / "my_cycles.toml"
    copy.write_text((LAYOUTS_DIR / "blender.toml").read_text())
    mine = get_layout(str(copy))
    assert mine.name == "my_cycles" and mine == load_layout(copy)
    path = _write_single(tmp_path / "f_0001.exr", blender_channels())
    _check_blender(read_frame(path, mine).buffers)
    assert get_layout("canonical").transforms == {}


MY_RENDERER = """
description = "a game engine's G-buffer dump"
required = ["color", "motion"]

[buffers.color]
layers = ["beauty"]

[buffers.normal]
layers = ["N"]
scale = 2.0          # stored as colours: n = 2 c - 1
offset = -1.0

[buffers.depth]
channels = ["Z"]

[buffers.motion]
channels = ["velocity.U", "velocity.V"]   # previous -> current, in UV units, y up
units = "uv"
scale = [-1.0, 1.0]
"""


def test_a_renderer_layout_file_converts_at_load_time(tmp_path):
    layout_file = tmp_path / "engine.toml"
    layout_file.write_text(MY_RENDERER)
    ch = {f"beauty.{c}": _chan(i + 1) for i, c in enumerate("RGB")}
    ch |= {f"N.{c}": _chan(v) for c, v in zip("RGB", (0.5, 1.0, 0.25), strict=True)}
    ch |= {"Z": _chan(3.0), "velocity.U": _chan(0.25), "velocity.V": _chan(0.5)}
    path = _write_single(tmp_path / "f_0007.exr", ch)
    buffers = read_frame(path, str(layout_file)).buffers
    np.testing.assert_array_equal(buffers["color"][:, 0, 0], [1, 2, 3])
    np.testing.assert_allclose(buffers["normal"][:, 0, 0], [0.0, 1.0, -0.5])
    assert buffers["depth"][0, 0, 0] == 3.0
    # (-0.25 * W, 0.5 * H) pixels with W = 8, H = 6
    np.testing.assert_allclose(buffers["motion"][:, 0, 0], [-2.0, 3.0])
    del ch["velocity.U"], ch["velocity.V"]  # required: a frame without it is refused
    _write_single(path, ch)
    with pytest.raises(InputError, match="missing channel velocity.U, velocity.V for buffer"):
        read_frame(path, str(layout_file))


@pytest.mark.parametrize(
    "text, match",
    [
        ("[buffers.colour]\nlayers = ['']", r"bad\.toml: needs at least \[buffers\.color\]"),
        (
            "[buffers.color]\nlayers = ['']\n[buffers.diffuse]\nlayers = ['d']",
            r"unknown buffer \[buffers\.diffuse\]; buffers: color, color_b",
        ),
        ("[buffers.color]\nlayer = ['']", r"buffers\.color: unknown key 'layer'; keys: layers"),
        ("[buffers.color]\nscale = 2.0", "give `layers` .* or `channels`"),
        (
            "[buffers.color]\nlayers = ['']\n[buffers.motion]\nlayers = ['mv']\nscale = [1, 2, 3]",
            r"buffers\.motion\.scale: expected a number or a list of 2 numbers",
        ),
        ("[buffers.color]\nlayers = ['']\nunits = 'uv'", "units apply to motion only"),
        ("[buffers.color]\nchannels = ['R', 'G']", r"channels: color needs 3 channel names"),
        ("[buffers.color]\nlayers = ['']\nclamp = [1, 0]", "low <= high"),
        ("name = 'x'\n[buffers.color]\nlayers = ['']", "unknown key 'name'; keys: description"),
        ("[buffers.color\n", "not a readable TOML layout file"),
    ],
)
def test_bad_layout_files_are_one_line_errors_naming_file_and_key(tmp_path, text, match):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=match) as info:
        get_layout(str(path))
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_the_docs_example_layout_reads_what_it_describes(tmp_path):
    """docs/layouts.md's worked example is a valid layout doing what its comments say."""
    docs = (Path(__file__).resolve().parents[1] / "docs" / "layouts.md").read_text()
    example = docs.split("### Example", 1)[1].split("```toml\n", 1)[1].split("```", 1)[0]
    layout_file = tmp_path / "renderer.toml"
    layout_file.write_text(example)
    ch = {f"beauty.{c}": _chan(2.0) for c in "RGB"}
    ch |= {f"diffuse_albedo.{c}": _chan(1.5) for c in "RGB"}
    ch |= {f"N_packed.{c}": _chan(v) for c, v in zip("RGB", (0.5, 0.5, 1.0), strict=True)}
    ch |= {"Z": _chan(4.0), "velocity.U": _chan(0.125), "velocity.V": _chan(0.5)}
    path = _write_single(tmp_path / "f_0001.exr", ch)
    b = read_frame(path, str(layout_file)).buffers
    np.testing.assert_allclose(b["albedo"][:, 0, 0], [1, 1, 1])
    np.testing.assert_allclose(b["normal"][:, 0, 0], [0, 0, 1])
    # moved +U (right) and +V (up) since the previous frame: previous = current + (-1, +3) px
    np.testing.assert_allclose(b["motion"][:, 0, 0], [-0.125 * W, 0.5 * H])


@pytest.mark.parametrize(
    "nested", ["a = " + "[" * 5000 + "]" * 5000, "a = " + "{b = " * 5000 + "1" + "}" * 5000]
)
def test_deeply_nested_layout_is_one_error_naming_the_file(tmp_path, nested):
    """Issue 27: a 5000-level TOML exited 1 with 'maximum recursion depth exceeded'."""
    path = tmp_path / "deep.toml"
    path.write_text(nested)
    with pytest.raises(InputError, match=r"deep\.toml: not a readable TOML layout file"):
        load_layout(path)
