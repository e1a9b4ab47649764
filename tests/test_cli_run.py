"""`denoise-run` end to end: pass-through, metrics JSON, previews, layouts and bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import OpenEXR
import pytest
from progress_lines import other_lines
from shipped_demos import SHIPPED_DEMOS
from typer.testing import CliRunner

import rtdenoise.runtime.sequences.frames as sequence
from rtdenoise.cli.run import DEFAULT_MODEL, app
from rtdenoise.runtime.sequences import metrics
from rtdenoise.runtime.sequences.exr import read_exr, write_exr
from rtdenoise.runtime.sequences.preview import encode_png, to_uint8

H, W = 64, 64
runner = CliRunner()


def make_sequence(folder, n=3, seed=0, refs=True):
    """Canonical frames frame_000k.exr (k = 1..n) with ref_000k.exr; returns (colors, refs)."""
    rng = np.random.default_rng(seed)
    colors, references = [], []
    for k in range(1, n + 1):
        ref = np.clip(rng.random((3, H, W)) * 2, 0, None).astype(np.float32)
        color = (ref * rng.exponential(1.0, (3, H, W))).astype(np.float32)  # noisy, mean = ref
        ch = {c: color[i] for i, c in enumerate("RGB")}
        ch |= {f"albedo.{c}": np.full((H, W), 0.5, np.float32) for c in "RGB"}
        ch |= {"depth.Z": np.ones((H, W), np.float32)}
        write_exr(folder / f"frame_{k:04d}.exr", ch, half=False)
        if refs:
            write_exr(folder / f"ref_{k:04d}.exr", {c: ref[i] for i, c in enumerate("RGB")})
            ref = np.stack([read_exr(folder / f"ref_{k:04d}.exr")[c] for c in "RGB"])
        colors.append(color)
        references.append(ref)
    return colors, references


def rgb(path):
    ch = read_exr(path)
    return np.stack([ch[c] for c in "RGB"])


def temp_files(folder):
    return [p.name for p in folder.rglob("*") if ".tmp" in p.name or p.name.startswith(".")]


def invoke(*args):
    """Run denoise-run; pass-through (`--model none`) unless the test names a model."""
    argv = [str(a) for a in args]
    if not {"--model", "-m", "--help"} & set(argv):
        argv += ["--model", "none"]
    return runner.invoke(app, argv)


def test_default_model_is_the_shipped_demo_and_help():
    assert DEFAULT_MODEL == "demo:nbg"
    # 200 columns: in rich's 80-column help table a long name is cut ("demo:affinity-sma…")
    res = CliRunner().invoke(app, ["--help"], env={"COLUMNS": "200"})
    assert res.exit_code == 0 and "blender" in res.stdout and "canonical" in res.stdout
    help_text = " ".join(res.stdout.replace("│", " ").split())
    for demo in SHIPPED_DEMOS:
        assert f"demo:{demo}" in help_text, demo  # --model names every shipped demo


def test_passthrough_outputs_json_and_previews(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    colors, refs = make_sequence(seq)
    js = tmp_path / "m.json"
    res = invoke(seq, "-o", out, "--metrics-json", js, "--preview")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == [
        f"frame_{k:04d}.{ext}" for k in (1, 2, 3) for ext in ("exr", "png")
    ]
    data = json.loads(js.read_text())
    assert set(data) >= {"frames", "mean", "trmae", "timing_ms", "input", "model"}
    assert set(data["timing_ms"]) == {"read", "denoise", "write"}
    assert set(data["mean"]) == {"psnr", "ssim", "smape", "relmse"}
    assert set(data["input"]) == {"psnr", "ssim", "smape", "relmse", "trmae"}
    for k, (row, color, ref) in enumerate(zip(data["frames"], colors, refs, strict=True), 1):
        assert {"index", "psnr", "ssim", "smape", "relmse"} <= set(row) and row["index"] == k
        written = rgb(out / f"frame_{k:04d}.exr")
        # pass-through: output == input colour within half precision
        np.testing.assert_allclose(written, color, rtol=2**-10, atol=1e-6)
        assert row["psnr"] == pytest.approx(metrics.psnr(written, ref), rel=1e-9)
        assert row["ssim"] == pytest.approx(metrics.ssim(written, ref), rel=1e-9)
        assert row["input"]["psnr"] == pytest.approx(metrics.psnr(color, ref), rel=1e-9)
    outputs = [rgb(out / f"frame_{k:04d}.exr") for k in (1, 2, 3)]
    pooled = np.mean([metrics.mse_tonemapped(o, r) for o, r in zip(outputs, refs, strict=True)])
    assert data["mean"]["psnr"] == pytest.approx(metrics.psnr_from_mse(pooled), rel=1e-9)
    expect_trmae = metrics.trmae(outputs, refs)
    assert data["trmae"] == pytest.approx(expect_trmae, rel=1e-6)
    assert 5 < data["mean"]["psnr"] < 40 and "PSNR" in res.stdout and "mean" in res.stdout


def test_float_output_and_reference_folder(tmp_path):
    seq, refdir, out = tmp_path / "seq", tmp_path / "gt", tmp_path / "out"
    seq.mkdir()
    refdir.mkdir()
    colors, refs = make_sequence(seq, n=2, refs=False)
    for k, ref in enumerate(colors, 1):  # references equal to the input: psnr inf -> null
        write_exr(refdir / f"gt.{k:03d}.exr", {c: ref[i] for i, c in enumerate("RGB")}, half=False)
    js = out / "metrics.json"
    res = invoke(
        str(seq / "frame_%04d.exr"), "-o", out, "--float", "-r", refdir, "--metrics-json", js
    )
    assert res.exit_code == 0, res.output
    np.testing.assert_array_equal(rgb(out / "frame_0002.exr"), colors[1])
    data = json.loads(js.read_text())
    assert data["frames"][0]["psnr"] is None and data["mean"]["smape"] == 0.0
    assert "inf" in res.stdout


def test_nonfinite_pixels_counted_reported_and_output_finite(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=2)
    ch = read_exr(seq / "frame_0002.exr")
    ch["R"][3, 4] = np.nan
    ch["G"][3, 4] = np.inf  # same pixel
    ch["B"][10, 11] = -np.inf
    write_exr(seq / "frame_0002.exr", ch, half=False)
    js = tmp_path / "m.json"
    res = invoke(seq, "-o", out, "--metrics-json", js)
    assert res.exit_code == 0, res.output
    assert "frame_0002.exr: 2 pixels with NaN/Inf in color replaced" in res.stderr
    written = rgb(out / "frame_0002.exr")
    assert np.isfinite(written).all() and written[0, 3, 4] == 0 and written[2, 10, 11] == 0
    data = json.loads(js.read_text())
    assert [f["nonfinite"] for f in data["frames"]] == [0, 2] and data["nonfinite"] == 2
    assert math.isfinite(data["mean"]["psnr"])


def _break_missing_channel(seq):
    ch = read_exr(seq / "frame_0002.exr")
    del ch["B"]
    write_exr(seq / "frame_0002.exr", ch)
    return "frame_0002.exr: missing channel B for buffer 'color'"


def _break_corrupt(seq):
    (seq / "frame_0002.exr").write_bytes(b"\x76\x2f\x31\x01" + b"garbage" * 50)
    return "frame_0002.exr: cannot read EXR"


def _break_truncated(seq):
    data = (seq / "frame_0002.exr").read_bytes()
    (seq / "frame_0002.exr").write_bytes(data[: len(data) * 2 // 3])
    return "frame_0002.exr: cannot read EXR"


def _break_resolution(seq):
    write_exr(seq / "frame_0003.exr", {c: np.ones((H, W + 2)) for c in "RGB"})
    return "frame_0003.exr: frame is 66x64 but"


def _break_reference(seq):
    write_exr(seq / "ref_0002.exr", {c: np.ones((H - 1, W)) for c in "RGB"})
    return "ref_0002.exr: frame is 64x63 but the sequence is 64x64"


BROKEN = {
    "reference": _break_reference,
    "missing_channel": _break_missing_channel,
    "corrupt": _break_corrupt,
    "truncated": _break_truncated,
    "resolution": _break_resolution,
}


@pytest.mark.parametrize("kind", list(BROKEN))
def test_bad_input_one_line_error_no_partial_files(tmp_path, kind):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq)
    expected = BROKEN[kind](seq)
    res = invoke(seq, "-o", out, "--preview")
    assert res.exit_code == 2
    lines = other_lines(res.stderr)  # after the frames done before the bad one
    assert len(lines) == 1 and lines[0].startswith("error: ") and expected in lines[0], res.stderr
    assert "Traceback" not in res.output
    if out.exists():
        assert temp_files(out) == []
        # complete frames before the bad one may stay; nothing of the bad frame or later
        assert all(p.name < "frame_0002" for p in out.iterdir())


@pytest.mark.parametrize(
    "args, expected",
    [
        (["-o", "{file}"], "output folder is a file"),
        (["-o", "{out}", "--layout", "arnold"], "unknown layout 'arnold'"),
        (
            ["-o", "{out}", "--channel", "albedo"],
            "bad --channel 'albedo': expected BUFFER=CHANNELS",
        ),
        (["-o", "{out}", "--channel", "spec=x.R"], "unknown buffer 'spec'"),
        (["-o", "{out}", "--channel", "albedo=Alb"], "missing channel Alb.R, Alb.G, Alb.B"),
        (["-o", "{seq}"], "writing the output would overwrite an input file"),
        (["-o", "{out}", "--model", "{tmp}/nope.onnx"], "nope.onnx: no such model file"),
        (["-o", "{out}", "-r", "{tmp}/nothing"], "nothing: no such file or folder"),
        (["--demo", "-o", "{out}"], "--demo takes no INPUT or --reference"),
        ([], "missing option -o/--output"),
    ],
)
def test_bad_arguments(tmp_path, args, expected):
    seq = tmp_path / "seq"
    seq.mkdir()
    make_sequence(seq, n=2)
    (tmp_path / "afile").write_text("x")
    fmt = {"file": tmp_path / "afile", "out": tmp_path / "out", "seq": seq, "tmp": tmp_path}
    res = invoke(seq, *[a.format(**fmt) for a in args])
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2 and len(lines) == 1, res.output
    assert lines[0].startswith("error: ") and expected in lines[0], lines[0]
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in seq.iterdir())[:2] == ["frame_0001.exr", "frame_0002.exr"]


def test_blender_multipart_sequence(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    rng = np.random.default_rng(3)
    noisy = {}
    for k in (1, 2):
        noisy[k] = rng.random((3, 16, 24), dtype=np.float32)
        passes = {
            "Noisy Image": dict(zip("RGB", noisy[k], strict=True)),
            "Combined": {c: np.zeros((16, 24), np.float32) for c in "RGBA"},
            "Vector": {c: np.ones((16, 24), np.float32) for c in "XYZW"},
        }
        parts = [
            OpenEXR.Part(
                {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                {f"ViewLayer.{p}.{c}": a for c, a in chans.items()},
                name=f"ViewLayer.{p}",
            )
            for p, chans in passes.items()
        ]
        OpenEXR.File(parts).write(str(seq / f"{k:04d}.exr"))
    res = invoke(seq, "-o", out, "--layout", "blender")
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(rgb(out / "0002.exr"), noisy[2], rtol=2**-10)
    res = invoke(seq, "-o", tmp_path / "o2")  # canonical layout: no R,G,B channels
    assert res.exit_code == 2 and "missing channel R, G, B for buffer 'color'" in res.stderr
    assert "(layout canonical, try --layout blender)" in res.stderr


def test_demo_runs_bundled_sequences(tmp_path, monkeypatch):
    import rtdenoise.shipped

    seqs = tmp_path / "sequences"
    (seqs / "cornell").mkdir(parents=True)
    colors, _ = make_sequence(seqs / "cornell", n=2)
    monkeypatch.setattr(rtdenoise.shipped, "sample_sequences", lambda: [seqs / "cornell"])
    js = tmp_path / "demo.json"
    res = invoke("--demo", "-o", tmp_path / "out", "--metrics-json", js)
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(
        rgb(tmp_path / "out" / "cornell" / "frame_0001.exr"), colors[0], rtol=2**-10, atol=1e-6
    )
    data = json.loads(js.read_text())
    assert [s["name"] for s in data["sequences"]] == ["cornell"]
    assert "cornell" in res.stdout and "PSNR" in res.stdout
    monkeypatch.setattr(rtdenoise.shipped, "sample_sequences", lambda: [])
    res = invoke("--demo", "-o", tmp_path / "out2")
    assert res.exit_code == 2 and "no bundled sample sequences" in res.stderr


def test_console_script_prints_exactly_one_line(tmp_path):
    """In a real process OpenEXR prints its own diagnostics on fds 1/2: they must not leak."""
    import subprocess
    import sys

    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    make_sequence(seq, n=2)
    expected = _break_truncated(seq)
    code = "from rtdenoise.cli.run import main; main()"
    proc = subprocess.run(
        [sys.executable, "-c", code, str(seq), "-o", str(out), "--model", "none"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.splitlines()[:-1] == [f"{seq}: frame 1/2"]  # a pipe: plain progress
    assert other_lines(proc.stderr) == [proc.stderr.splitlines()[-1]]
    assert proc.stderr.endswith("\n") and proc.stderr.splitlines()[-1].startswith("error: ")
    assert expected in proc.stderr
    assert temp_files(out) == [] and [p.name for p in out.iterdir()] == ["frame_0001.exr"]


def test_onnx_model_with_state_through_the_cli(tmp_path, monkeypatch):
    """A contract-v1 ONNX model (tests/contract_models.py EMA) through --model: state is fed
    back frame to frame and reset at the start of every sequence."""
    from contract_models import EmaReference, ema_model

    import rtdenoise.shipped

    model = tmp_path / "ema.onnx"
    model.write_bytes(ema_model())
    seqs = [tmp_path / "a", tmp_path / "b"]
    colors = {}
    for i, s in enumerate(seqs):
        s.mkdir()
        colors[s.name], _ = make_sequence(s, n=3 - i, seed=i)
    monkeypatch.setattr(rtdenoise.shipped, "sample_sequences", lambda: seqs)
    out = tmp_path / "out"
    res = invoke("--demo", "-o", out, "--model", model, "--float", "--threads", 1)
    assert res.exit_code == 0, res.output
    for s in seqs:
        ref = EmaReference()
        for k, color in enumerate(colors[s.name], 1):
            expected = ref.step(color, np.full_like(color, 0.5), reset=k == 1)
            got = rgb(out / s.name / f"frame_{k:04d}.exr")
            np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    res = invoke(seqs[0], "-o", tmp_path / "o2", "--model", model, "--channel", "albedo=none")
    assert res.exit_code == 2 and "the model needs buffer 'albedo'" in res.stderr
    assert not (tmp_path / "o2").exists()


@pytest.mark.parametrize("half", [True, False])
def test_metrics_are_those_of_the_written_file(tmp_path, half):
    """The scored (and previewed) array is exactly the one in the output file: re-reading
    the outputs gives the JSON's metrics bit for bit, clamped half-range values included."""
    seq, out = tmp_path / "seq", tmp_path / "out"
    seq.mkdir()
    colors, refs = make_sequence(seq, n=3)
    ch = read_exr(seq / "frame_0002.exr")
    ch["G"][1, 2], ch["B"][5, 6] = 1e6, 70000.0  # beyond half range: stored as 65504
    write_exr(seq / "frame_0002.exr", ch, half=False)
    js = tmp_path / "m.json"
    res = invoke(seq, "-o", out, "--metrics-json", js, "--preview", "--half" if half else "--float")
    assert res.exit_code == 0, res.output
    data = json.loads(js.read_text())
    written = [rgb(out / f"frame_{k:04d}.exr") for k in (1, 2, 3)]
    assert written[1][1, 1, 2] == (65504.0 if half else 1e6)
    expected = metrics.SequenceMetrics()
    for row, w, ref, k in zip(data["frames"], written, refs, (1, 2, 3), strict=True):
        got = expected.add(w, ref)
        assert {key: row[key] for key in got} == got
        assert (out / f"frame_{k:04d}.png").read_bytes() == encode_png(to_uint8(w))
    summary = expected.summary()
    assert data["mean"] == {key: summary[key] for key in ("psnr", "ssim", "smape", "relmse")}
    assert data["trmae"] == summary["trmae"]


def _with_albedo(seq, k, albedo):
    """Replace frame k's albedo layer: None drops it, else an (h, w) array (another part)."""
    ch = read_exr(seq / f"frame_{k:04d}.exr")
    for c in "RGB":
        del ch[f"albedo.{c}"]
    path = seq / f"frame_{k:04d}.exr"
    if albedo is None:
        write_exr(path, ch, half=False)
        return
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    windows = [((0, 0), (W - 1, H - 1)), ((0, 0), (albedo.shape[1] - 1, albedo.shape[0] - 1))]
    parts = []
    for i, (chans, win) in enumerate(
        zip([ch, {f"albedo.{c}": albedo for c in "RGB"}], windows, strict=True)
    ):
        hdr = header | {
            "displayWindow": tuple(np.array(v, np.int32) for v in windows[0]),
            "dataWindow": tuple(np.array(v, np.int32) for v in win),
        }
        parts.append(OpenEXR.Part(hdr, chans, name=f"p{i}"))
    OpenEXR.File(parts).write(str(path))


@pytest.mark.parametrize("albedo", ["absent", "wrong size"])
def test_only_the_buffers_the_model_needs_are_read(tmp_path, albedo):
    """An unused layer may be absent or of another size; a needed one is an error naming
    the file and the channel, before any output is written."""
    from contract_models import ema_model

    seq = tmp_path / "seq"
    seq.mkdir()
    make_sequence(seq, n=3)
    _with_albedo(seq, 2, None if albedo == "absent" else np.ones((H + 2, W), np.float32))
    res = invoke(seq, "-o", tmp_path / "none")  # pass-through needs only color
    assert res.exit_code == 0, res.output
    assert len(list((tmp_path / "none").glob("*.exr"))) == 3
    model = tmp_path / "ema.onnx"  # needs color and albedo
    model.write_bytes(ema_model())
    res = invoke(seq, "-o", tmp_path / "ema", "--model", model)
    assert res.exit_code == 2
    expected = {
        "absent": "missing channel albedo.R, albedo.G, albedo.B for buffer 'albedo'",
        "wrong size": "channel 'albedo.R' is 64x66 but channel 'R' is 64x64",
    }[albedo]
    expected = f"{seq / 'frame_0002.exr'}: {expected}"
    assert expected in res.stderr and res.stderr.count("\n") == 1, res.stderr
    assert not (tmp_path / "ema").exists()


def test_channels_resolved_once_per_sequence(tmp_path, monkeypatch):
    seq = tmp_path / "seq"
    seq.mkdir()
    make_sequence(seq, n=4)
    resolves, reads = [], []
    real_resolve, real_read = sequence.resolve_channels, sequence.read_exr

    def resolve(*args, **kwargs):
        resolves.append(args[-1] if len(args) > 3 else kwargs.get("source"))
        return real_resolve(*args, **kwargs)

    def read(path, channels=None, **kwargs):
        reads.append((path.name, channels))
        return real_read(path, channels, **kwargs)

    monkeypatch.setattr(sequence, "resolve_channels", resolve)
    monkeypatch.setattr(sequence, "read_exr", read)
    res = invoke(seq, "-o", tmp_path / "out")
    assert res.exit_code == 0, res.output
    assert resolves == [str(seq / "frame_0001.exr")]  # once, from the first frame's header
    frames = [r for r in reads if r[0].startswith("frame_")]
    assert frames == [(f"frame_{k:04d}.exr", ["R", "G", "B"]) for k in (1, 2, 3, 4)]
    assert all(c == list("RGB") for name, c in reads if name.startswith("ref_"))


def test_several_inputs_are_several_shots(tmp_path):
    """Two folders with the same frame numbers: two sequences (state reset each), each into
    OUT/<shot>/, one JSON with both; same folder names are told apart by their parents."""
    shots = [tmp_path / "a" / "render", tmp_path / "b" / "render", tmp_path / "c"]
    colors = {}
    for i, s in enumerate(shots):
        s.mkdir(parents=True)
        colors[s], _ = make_sequence(s, n=2, seed=i)
    out, js = tmp_path / "out", tmp_path / "m.json"
    glob = str(shots[2] / "frame_*.exr")
    res = invoke(shots[0], shots[1], glob, "-o", out, "--metrics-json", js)
    assert res.exit_code == 0, res.output
    names = ["a/render", "b/render", "c"]
    assert [s["name"] for s in json.loads(js.read_text())["sequences"]] == names
    for name, s in zip(names, shots, strict=True):
        got = rgb(out / name / "frame_0002.exr")
        np.testing.assert_allclose(got, colors[s][1], rtol=2**-10, atol=1e-6)
    assert "over 3 sequences" in res.stdout


def test_files_listed_one_by_one_are_one_shot(tmp_path):
    """An unquoted glob the shell expanded: the files of one folder stay one sequence."""
    seq = tmp_path / "seq"
    seq.mkdir()
    make_sequence(seq, n=3)
    files = sorted(p for p in seq.glob("frame_*.exr"))
    res = invoke(*files, "-o", tmp_path / "out")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [p.name for p in files]


def test_several_shots_refuse_one_reference_and_two_patterns_in_a_folder(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for s in (a, b):
        s.mkdir()
        make_sequence(s, n=1)
    res = invoke(a, b, "-o", tmp_path / "o", "--reference", a)
    assert res.exit_code == 2 and "--reference names the references of one shot" in res.stderr
    res = invoke(a / "frame_*.exr", a / "frame_%04d.exr", "-o", tmp_path / "o")
    assert res.exit_code == 2 and "are two shots in one folder" in res.stderr
    assert not (tmp_path / "o").exists()


def test_provider_choice(tmp_path):
    from contract_models import ema_model

    seq, model = tmp_path / "seq", tmp_path / "ema.onnx"
    seq.mkdir()
    make_sequence(seq, n=1, refs=False)
    model.write_bytes(ema_model())
    res = invoke(seq, "-o", tmp_path / "out", "--model", model, "--provider", "cpu")
    assert res.exit_code == 0, res.output
    res = invoke(seq, "-o", tmp_path / "o2", "--model", model, "-p", "NopeExecutionProvider")
    assert res.exit_code == 2
    assert "execution provider 'NopeExecutionProvider' is not available" in res.stderr
    assert "CPUExecutionProvider" in res.stderr and res.stderr.count("\n") == 1


def test_layout_file_and_show_layout(tmp_path):
    """`--show-layout blender` prints the preset; an edited copy is a `--layout` file."""
    res = invoke("--show-layout", "blender")
    assert res.exit_code == 0 and "[buffers.motion]" in res.stdout
    text = res.stdout.replace('layers = ["Noisy Image", "Combined"]', 'layers = ["beauty"]')
    mine = tmp_path / "my_renderer.toml"
    mine.write_text(text)
    seq = tmp_path / "seq"
    seq.mkdir()
    noisy = np.random.default_rng(0).random((3, H, W), dtype=np.float32)
    write_exr(seq / "f_0001.exr", {f"beauty.{c}": noisy[i] for i, c in enumerate("RGB")})
    res = invoke(seq, "-o", tmp_path / "out", "--layout", mine)
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(rgb(tmp_path / "out" / "f_0001.exr"), noisy, rtol=2**-10, atol=1e-6)
    res = invoke(seq, "-o", tmp_path / "o2", "--layout", tmp_path / "missing.toml")
    assert res.exit_code == 2 and "missing.toml: no such layout file" in res.stderr


def test_a_model_that_needs_color_b_says_how_to_make_it(tmp_path):
    """Files without colorB (most renderers write none): the error names the buffer and says
    how to produce it; nothing is written."""
    make_sequence(tmp_path / "seq", n=2)  # R,G,B, albedo, normal, depth, motion: no colorB
    res = invoke(tmp_path / "seq", "-o", tmp_path / "out", "--model", "demo:crossreg")
    assert res.exit_code == 2
    text = " ".join(res.output.split())
    assert "missing channel colorB.R, colorB.G, colorB.B for buffer 'color_b'" in text
    assert "render each frame twice with different seeds" in text
    assert "--channel color_b=LAYER" in text
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())
