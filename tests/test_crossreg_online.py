"""demo:crossreg learns while it runs, inside ONNX Runtime, with torch blocked: over a committed
sequence played three times in a row (24 frames; the wrap is a camera jump the reprojection
rejects), frames 10-20 are better with learning than with the weights frozen at their
initialisation; --learn-every / --no-online reach the graph through the runtime and denoise-run.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rtdenoise.shipped import MODELS_DIR, sample_sequences

pytestmark = pytest.mark.skipif(
    not (MODELS_DIR / "crossreg.onnx").is_file(), reason="demo:crossreg is not shipped"
)

LEARN_SEQUENCE = 2  # seq_002 (see the README note for all three committed sequences)

# the start of each script below: torch blocked, then the runtime and the metric
TORCH_BLOCKED = textwrap.dedent(
    """
    import json, sys
    sys.modules["torch"] = None  # any `import torch` now raises ImportError
    import numpy as np
    from rtdenoise.runtime import Denoiser
    from rtdenoise.runtime.sequences.metrics import mse_tonemapped, psnr_from_mse
    from rtdenoise.runtime.sequences.frames import (
        find_frames,
        match_references,
        read_frame,
        read_reference,
        shot_cuts,
    )
    """
)

SCRIPT = TORCH_BLOCKED + textwrap.dedent(
    """
    paths = find_frames(sys.argv[1])
    frames = [read_frame(p).buffers for p in paths] * 3
    refs = [read_reference(r) for r in match_references(paths)] * 3
    result = {"noisy": psnr_from_mse(np.mean([mse_tonemapped(f["color"], r)
                                              for f, r in zip(frames[10:21], refs[10:21])]))}
    for learn in (True, False):
        den = Denoiser("demo:crossreg", learn=learn)
        mses = [mse_tonemapped(den.process(f), r) for f, r in zip(frames, refs)]
        key = "learn" if learn else "frozen"
        result[key] = psnr_from_mse(float(np.mean(mses[10:21])))
        result[key + "_steps"] = float(den.state_value("adam_t").ravel()[0])
        result[key + "_loss"] = float(den.state_value("loss").ravel()[0])
    result["torch"] = repr(sys.modules.get("torch", "absent"))
    print(json.dumps(result))
    """
)


def test_online_learning_improves_frames_10_to_20_with_torch_blocked():
    seq = sample_sequences()[LEARN_SEQUENCE]
    proc = subprocess.run(
        [sys.executable, "-W", "ignore", "-c", SCRIPT, str(seq)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["torch"] == "None"  # the learning ran without torch
    assert result["learn_steps"] == 24.0 and result["frozen_steps"] == 0.0
    assert result["learn_loss"] > 0 and result["frozen_loss"] > 0
    # measured (PSNR of frames 10-20): learning 23.33 dB, frozen 23.02 dB, noisy 18.55 dB (the
    # gain curve binned by each pixel's own output brightness had lost here, 22.74: see
    # models/gain_curve.py `guide`)
    assert result["learn"] > result["frozen"] + 0.05, result
    assert result["frozen"] > result["noisy"] + 3.0, result


LONG_SEQUENCE = Path(__file__).resolve().parents[1] / "validation" / "long_000"

LONG_SCRIPT = TORCH_BLOCKED + textwrap.dedent(
    """
    paths = find_frames(sys.argv[1])
    cuts = set(shot_cuts(sys.argv[1]))
    frames = [read_frame(p).buffers for p in paths]
    refs = [read_reference(r) for r in match_references(paths)]
    result = {"frames": len(frames), "cuts": sorted(cuts)}
    for key, learn in (("learn", True), ("frozen", False)):
        den = Denoiser("demo:crossreg", learn=learn)
        mses = [mse_tonemapped(den.process(f, reset=t in cuts), r)
                for t, (f, r) in enumerate(zip(frames, refs))]
        result[key] = psnr_from_mse(float(np.mean(mses[8:])))
    result["torch"] = repr(sys.modules.get("torch", "absent"))
    print(json.dumps(result))
    """
)


def test_online_learning_beats_frozen_after_frame_8_of_a_64_frame_sequence():
    """Issue 25's acceptance check on the committed 64-frame sequence (validation/long_000: a
    room, a camera cut at frame 25 that keeps the learning): frames 8-63 pooled, learning
    against the weights and gain curve frozen at the shipped init, in ONNX Runtime with torch
    blocked. Measured: learning 25.89 dB, frozen 21.62 (theta's update alone, without the gain
    curve, had lost: 21.47 against 21.62; the gain undoes the log domain's darkening, which no
    theta can)."""
    proc = subprocess.run(
        [sys.executable, "-W", "ignore", "-c", LONG_SCRIPT, str(LONG_SEQUENCE)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr)
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    if not (result["torch"] == "None" and result["frames"] == 64 and result["cuts"] == [25]):
        raise RuntimeError(f"not the run this test makes: {result}")
    assert result["learn"] > result["frozen"] + 3.0, result


def test_learn_every_and_no_online_reach_the_graph(tmp_path):
    import numpy as np
    from typer.testing import CliRunner

    from rtdenoise.cli.run import app
    from rtdenoise.runtime import Denoiser
    from rtdenoise.runtime.sequences.frames import find_frames, read_frame

    seq = sample_sequences()[0]
    frames = [read_frame(p).buffers for p in find_frames(seq)]
    every4 = Denoiser("demo:crossreg", learn_every=4)
    theta, curve = [], []
    for frame in frames:
        every4.process(frame)
        theta.append(every4.state_value("theta").ravel())
        curve.append(every4.state_value("gain_curve").ravel())
    assert float(every4.state_value("adam_t").ravel()[0]) == 2.0  # frames 0 and 4
    for learned in (theta, curve):  # the weights and the gain curve: frames 0 and 4 only
        moved = [not np.array_equal(a, b) for a, b in zip(learned[:-1], learned[1:], strict=True)]
        assert moved == [False, False, False, True, False, False, False]
    assert np.abs(curve[0]).sum() > 0
    assert every4.online["layout"][0] == {"name": "encoders.0.0.weight", "shape": [8, 15, 3, 3]}

    runner = CliRunner()
    res = runner.invoke(app, [str(seq), "-o", str(tmp_path / "a"), "-m", "demo:crossreg",
                              "--learn-every", "4"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "online learning (every 4 frames): 2 update steps" in res.output
    res = runner.invoke(app, [str(seq), "-o", str(tmp_path / "b"), "-m", "demo:crossreg",
                              "--no-online"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "online learning off" in res.output


def test_stage_benchmark_assigns_every_node_and_runs(tmp_path):
    """The ORT nodes of the online graph fall into the stages the way the graph is built: the
    regression and filter ops, the forward U-Net (its 12 convolutions), backward + Adam
    (convolutions, ConvWeightGrad ops and matrix products for the gradients, the max-pool
    scatters), all of it inside the learning If (its then-branch), the reprojection (one
    SvgfReproject node) in `other`; `denoise-bench stages` runs at a tiny size."""
    from collections import Counter

    import onnx
    from typer.testing import CliRunner

    from rtdenoise.cli.bench import app
    from rtdenoise.export.learning_branch import all_nodes
    from rtdenoise.export.stage_bench import node_stages

    proto = onnx.load(MODELS_DIR / "crossreg.onnx")
    online = json.loads({p.key: p.value for p in proto.metadata_props}["rtdenoise.online"])
    stages = node_stages(proto, online)
    (branch,) = [n for n in proto.graph.node if n.op_type == "If"]
    assert stages[branch.name] is None  # not counted: its time is its branch's nodes'
    ops = {stage: Counter() for stage in set(stages.values())}
    for node in all_nodes(proto.graph):
        ops[stages[node.name]][node.op_type] += 1
    # outside the If only its condition (from freeze) and the learned states' reshapes
    outside = {n.op_type for n in proto.graph.node if stages[n.name] == "backward + adam"}
    assert outside <= {"Clip", "Sub", "Greater", "Reshape"}
    assert ops["regression"] == Counter({"CrossRegression": 1})
    assert ops["filter"] == Counter({"CrossBilateralFilter": 1})
    assert ops["unet"]["Conv"] == 10 and ops["unet"]["ConvTranspose"] == 2  # the forward pass
    assert ops["unet"]["MaxPool"] == 2
    assert ops["backward + adam"]["ScatterElements"] == 2  # max-pool backward
    # input gradients of the 10 convolutions but the first (the network input needs none), as
    # forward convolutions with flipped weights (ORT's ConvTranspose is 20x slower there), and
    # of the 2 transposed convs; weight gradients: one ConvWeightGrad per 3x3 conv (9), one
    # MatMul for the 1x1 head and each of the 2 1x1 transposed convs
    assert "ConvTranspose" not in ops["backward + adam"]
    assert ops["backward + adam"]["Conv"] == 9 + 2
    assert ops["backward + adam"]["ConvWeightGrad"] == 9
    assert ops["backward + adam"]["MatMul"] == 1 + 2
    assert "Conv" not in ops["other"] and "ConvTranspose" not in ops["other"]
    assert ops["other"]["SvgfReproject"] == 1  # the history warp: no gathers left
    # the warp has no gathers; the gain curve reads its two nodes around each pixel
    assert sum(counts["GatherElements"] for counts in ops.values()) == 2
    out = tmp_path / "stages.json"
    res = CliRunner().invoke(
        app, ["stages", "demo:crossreg", "--size", "32x32", "--repeats", "1", "--json", str(out)]
    )
    assert res.exit_code == 0, res.output
    paths = json.loads(out.read_text())["paths"]
    assert set(paths) == {"torch", "ort_fast", "ort_portable"}
    for stage in ("regression", "unet", "filter", "backward + adam"):
        assert paths["torch"]["stages"][stage] > 0 and paths["ort_fast"]["stages"][stage] > 0


def test_stage_benchmark_counts_the_nodes_ort_renames(tmp_path):
    """ONNX Runtime renames the nodes it fuses or rewrites (`node_mm/MatmulTransposeFusion/`,
    `..._token_3`) and makes some of its own (NCHWc reorders, transposes): the stage split
    maps each back to its node's stage, an ORT-made node to the stage of the node it feeds
    (`ReorderOutput`: of its producer). Counted as `other`, the weight gradients' fused
    products had left backward + Adam at 0.97x of eager's time where it was about 2x."""
    from rtdenoise.export.stage_bench import NEXT, PREVIOUS, node_ms_per_run, profiled_stage

    stages = {"node_mm": "backward + adam", "a/b": "unet", "If_0": None, "node_relu": "unet"}
    assert profiled_stage("node_mm/MatmulTransposeFusion/", stages) == "backward + adam"
    assert profiled_stage("a/b", stages) == "unet"  # an original name with a slash
    assert profiled_stage("a/b_token_7", stages) == "unet"
    assert profiled_stage("a/b/GatherSliceToSplitFusion_token_2", stages) == "unet"
    assert profiled_stage("If_0", stages) is None
    assert profiled_stage("ReorderInput_token_4", stages) == NEXT
    assert profiled_stage("ReorderOutput_token_5", stages) == PREVIOUS
    assert profiled_stage("Transpose_token_0", stages) == NEXT

    def event(name: str, ts: int, dur: int) -> dict:
        return {"cat": "Node", "name": f"{name}_kernel_time", "ts": ts, "dur": dur,
                "args": {"op_name": "X"}}  # fmt: skip

    run = [
        ("ReorderInput_token_1", 1, 1000),  # -> the next node's stage (unet)
        ("ReorderInput_token_2", 2, 2000),
        ("node_relu_token_3", 3, 4000),
        ("ReorderOutput_token_4", 4, 8000),  # -> the previous node's (unet)
        ("If_0", 5, 99000),  # not counted
        ("Transpose_token_0", 6, 16000),  # -> backward + adam
        ("node_mm/MatmulTransposeFusion/", 7, 32000),
        ("Transpose_token_9", 8, 64000),  # nothing after it: other
    ]
    profile = tmp_path / "profile.json"
    events = [{"name": "model_run", "ts": 0, "dur": 100}] + [event(*e) for e in run]
    profile.write_text(json.dumps(events))
    (ms,) = node_ms_per_run(str(profile), lambda name, _op: profiled_stage(name, stages))
    assert dict(ms) == {"unet": 15.0, "backward + adam": 48.0, "other": 64.0}


def _theta_and_step(den) -> tuple:
    return den.state_value("theta").ravel(), float(den.state_value("adam_t").ravel()[0])


def _curve(den):
    return den.state_value("gain_curve").ravel()


def test_a_cut_keeps_the_learning_unless_asked():
    """reset() restarts the history, not the learning: the weights, Adam's moments and step
    and the gain curve carry over (a size change and an unusable frame too);
    reset(learning=True) and relearn_at_cuts restart them."""
    import numpy as np

    from rtdenoise.runtime import Denoiser
    from rtdenoise.runtime.sequences.frames import find_frames, read_frame

    frames = [read_frame(p).buffers for p in find_frames(sample_sequences()[0])]
    init = Denoiser("demo:crossreg", learn=False)
    init.process(frames[0])
    theta0, _ = _theta_and_step(init)

    den = Denoiser("demo:crossreg")
    for frame in frames[:3]:
        den.process(frame)
    learned, steps = _theta_and_step(den)
    curve = _curve(den)
    assert steps == 3.0 and not np.array_equal(learned, theta0)
    assert np.abs(curve).sum() > 0 and not np.abs(_curve(init)).any()
    den.reset()
    den.learn = False  # a frozen frame shows which weights it started from
    den.process(frames[3])
    assert den.frame_index == 1
    kept, steps = _theta_and_step(den)
    np.testing.assert_array_equal(kept, learned)
    np.testing.assert_array_equal(_curve(den), curve)
    assert steps == 3.0
    den.process({k: v[..., :48, :56] for k, v in frames[4].items()})  # a new size: a new history
    np.testing.assert_array_equal(_theta_and_step(den)[0], learned)
    np.testing.assert_array_equal(_curve(den), curve)
    unusable = {**frames[5], "albedo": np.zeros_like(frames[5]["albedo"])}  # a missing pass
    den.process(unusable)
    assert den.last_guard.reset and den.last_guard.unusable == ("albedo",)
    np.testing.assert_array_equal(_theta_and_step(den)[0], learned)
    np.testing.assert_array_equal(_curve(den), curve)
    den.reset(learning=True)
    den.process(frames[0])
    relearned, steps = _theta_and_step(den)
    np.testing.assert_array_equal(relearned, theta0)
    assert steps == 0.0 and not np.abs(_curve(den)).any()

    every_cut = Denoiser("demo:crossreg", relearn_at_cuts=True)
    for frame in frames[:2]:
        every_cut.process(frame)
    every_cut.reset()
    every_cut.learn = False
    every_cut.process(frames[2])
    np.testing.assert_array_equal(_theta_and_step(every_cut)[0], theta0)


def test_relearn_at_cuts_on_the_command_line(tmp_path):
    """A gap in the frame numbers is a cut: the update steps of the sequence go on over it, or
    start again after it with --relearn-at-cuts."""
    import shutil

    from typer.testing import CliRunner

    from rtdenoise.cli.run import app

    seq = tmp_path / "seq"
    seq.mkdir()
    for path in sorted(sample_sequences()[0].glob("*_000[0-6].exr")):
        if "0003" not in path.name:  # frames 0-2, then 4-6
            shutil.copy(path, seq / path.name)
    runner = CliRunner()
    kept = runner.invoke(app, [str(seq), "-o", str(tmp_path / "a"), "-m", "demo:crossreg"])
    assert kept.exit_code == 0, kept.output
    assert "6 update steps" in kept.output
    again = runner.invoke(app, [str(seq), "-o", str(tmp_path / "b"), "-m", "demo:crossreg",
                                "--relearn-at-cuts"])  # fmt: skip
    assert again.exit_code == 0, again.output
    assert "3 update steps" in again.output


def test_frozen_frames_run_no_backward_node(tmp_path):
    """freeze = 1 (--no-online, the frames --learn-every skips) runs none of the backward pass
    and Adam nodes (the learning If's then-branch), by ONNX Runtime's own profile; a learning
    frame runs them."""
    import numpy as np
    import onnx
    import onnxruntime as ort

    from rtdenoise.export.learning_branch import all_nodes
    from rtdenoise.export.stage_bench import node_ms_per_run
    from rtdenoise.runtime.contract import RESET, contract_from_session
    from rtdenoise.runtime.sequences.synthetic import synthetic_frames

    proto = onnx.load(MODELS_DIR / "crossreg.onnx")
    (branch,) = [n for n in proto.graph.node if n.op_type == "If"]
    then = next(a.g for a in branch.attribute if a.name == "then_branch")
    update = {n.name for n in all_nodes(then)}
    assert len(update) > 200 and all(update)
    assert {"Conv", "ScatterElements"} <= {n.op_type for n in then.node}
    so = ort.SessionOptions()
    so.enable_profiling = True
    so.profile_file_prefix = str(tmp_path / "ort")
    session = ort.InferenceSession(proto.SerializeToString(), so, ["CPUExecutionProvider"])
    contract = contract_from_session(session)
    frame = synthetic_frames(contract.buffer_names, 1, 32, 32)[0]
    for freeze in (1.0, 0.0, 1.0):
        feed = {name: frame[name][None] for name in contract.buffer_names}
        feed[RESET] = np.array(1.0, np.float32)
        for s in contract.state:
            feed[s.input_name] = np.full(s.shape(32, 32), freeze if s.name == "freeze" else 0.0,
                                         np.float32)  # fmt: skip
        session.run(None, feed)
    runs = node_ms_per_run(
        session.end_profiling(), lambda name, _op: "update" if name in update else "rest"
    )
    frozen, learning, frozen_again = ({k: v > 0 for k, v in run.items()} for run in runs)
    assert "update" not in frozen and "update" not in frozen_again
    assert learning["update"] and frozen["rest"]
