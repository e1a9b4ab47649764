"""The runtime's own check of ONNX external-data locations (runtime/external_data.py): inside
the model's folder, no symlinks out, whatever the onnxruntime version."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import onnx
import pytest
from contract_models import ema_model
from onnx import helper, numpy_helper
from onnx.external_data_helper import convert_model_to_external_data

from rtdenoise.runtime import Denoiser, InputError
from rtdenoise.runtime.external_data import check_external_data, external_locations


def save_external(folder: Path, location: str = "w.bin") -> Path:
    """The ema contract model with its 3x3 box weights in the side file `location`."""
    model = onnx.load_from_string(ema_model())
    convert_model_to_external_data(model, location=location, size_threshold=100)
    (folder / location).parent.mkdir(parents=True, exist_ok=True)
    path = folder / "m.onnx"
    onnx.save_model(model, path)
    return path


def relocate(path: Path, location: str) -> None:
    """Point every external tensor of the model at `location` (the file is not moved)."""
    model = onnx.load(path, load_external_data=False)
    for t in model.graph.initializer:
        for entry in t.external_data:
            if entry.key == "location":
                entry.value = location
    path.write_bytes(model.SerializeToString())


def test_external_data_inside_the_folder_runs(tmp_path):
    path = save_external(tmp_path / "model")
    assert external_locations(path.read_bytes()) == ["w.bin"]
    assert check_external_data(path) == [(tmp_path / "model" / "w.bin").resolve()]
    den = Denoiser(path, fast_kernels=False)
    ones = np.ones((3, 8, 8), np.float32)
    out = den.process({"color": ones, "albedo": 0.5 * ones})
    np.testing.assert_allclose(out[:, 2:6, 2:6], 0.5, rtol=1e-6)  # box of ones = 1, x 0.5
    sub = save_external(tmp_path / "nested", "data/w.bin")  # a subfolder is inside
    assert check_external_data(sub) == [(tmp_path / "nested" / "data" / "w.bin").resolve()]


@pytest.mark.parametrize(
    ("location", "match"),
    [
        ("../secret.bin", r"'\.\./secret\.bin' points outside the model's folder"),
        ("data/../../secret.bin", "points outside the model's folder"),
        ("/etc/hostname", r"'/etc/hostname' is an absolute path"),
        ("missing.bin", r"external data file 'missing\.bin' not found"),
        ("link.bin", r"'link\.bin' points outside the model's folder"),  # a symlink out
    ],
)
def test_locations_outside_the_folder_are_refused(tmp_path, location, match):
    path = save_external(tmp_path / "model")
    (tmp_path / "secret.bin").write_bytes((tmp_path / "model" / "w.bin").read_bytes())
    os.symlink(tmp_path / "secret.bin", tmp_path / "model" / "link.bin")
    relocate(path, location)
    with pytest.raises(InputError, match=match) as info:
        Denoiser(path, fast_kernels=False)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_symlink_inside_the_folder_is_fine(tmp_path):
    path = save_external(tmp_path / "model")
    os.symlink(tmp_path / "model" / "w.bin", tmp_path / "model" / "alias.bin")
    relocate(path, "alias.bin")
    assert check_external_data(path) == [(tmp_path / "model" / "w.bin").resolve()]


def test_model_bytes_with_external_data_are_refused(tmp_path):
    path = save_external(tmp_path / "model")
    with pytest.raises(InputError, match=r"keeps tensor data in 'w\.bin'; give its path"):
        Denoiser(path.read_bytes(), fast_kernels=False)
    assert check_external_data(ema_model()) == []  # no external data: fine as bytes


def test_locations_found_in_nested_graphs_functions_and_attributes():
    """Tensors hide in Constant attributes, If branches and model-local function bodies."""

    def external(name: str, location: str) -> onnx.TensorProto:
        t = numpy_helper.from_array(np.zeros(2, np.float32), name)
        t.ClearField("raw_data")
        t.data_location = onnx.TensorProto.EXTERNAL
        t.external_data.add(key="location", value=location)
        t.external_data.add(key="offset", value="0")
        return t

    const = helper.make_node("Constant", [], ["c"], value=external("v", "../in_attribute"))
    branch = helper.make_graph(
        [helper.make_node("Constant", [], ["b"], value=external("w", "/in_branch"))],
        "branch",
        [],
        [helper.make_tensor_value_info("b", onnx.TensorProto.FLOAT, [2])],
    )
    cond = helper.make_node("If", ["flag"], ["y"], then_branch=branch, else_branch=branch)
    graph = helper.make_graph(
        [const, cond],
        "g",
        [helper.make_tensor_value_info("flag", onnx.TensorProto.BOOL, [])],
        [helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [2])],
        [external("init", "weights.bin")],
    )
    function = helper.make_function(
        "custom",
        "F",
        [],
        ["o"],
        [helper.make_node("Constant", [], ["o"], value=external("f", "../in_function"))],
        [helper.make_opsetid("", 18)],
    )
    model = helper.make_model(graph, functions=[function])
    found = external_locations(model.SerializeToString())
    assert sorted(found) == sorted(
        ["weights.bin", "../in_attribute", "/in_branch", "/in_branch", "../in_function"]
    )


def test_malformed_protobuf_is_one_clear_error(tmp_path):
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x0a\xff\xff\xff\x0f location")  # a field longer than the file
    with pytest.raises(InputError, match=r"bad\.onnx: not a well-formed ONNX protobuf"):
        check_external_data(bad)


def test_model_symlink_is_checked_where_onnx_runtime_reads(tmp_path):
    """Issue 27, item 1: B/m.onnx -> A/m.onnx with B/w.bin -> any file. ONNX Runtime reads
    B/w.bin (beside the path it was given), so the check must look there, not beside A/m.onnx."""
    real = save_external(tmp_path / "A")
    (tmp_path / "B").mkdir()
    (tmp_path / "other.bin").write_bytes(b"\x7f" * (tmp_path / "A" / "w.bin").stat().st_size)
    os.symlink(real, tmp_path / "B" / "m.onnx")
    os.symlink(tmp_path / "other.bin", tmp_path / "B" / "w.bin")
    link = tmp_path / "B" / "m.onnx"
    with pytest.raises(InputError, match=r"'w\.bin' points outside the model's folder") as info:
        Denoiser(link, fast_kernels=False)
    assert str(link) in str(info.value) and str(tmp_path / "B") in str(info.value)


def test_model_symlink_into_another_folder_with_data_is_refused_on_every_version(tmp_path):
    """ONNX Runtime 1.32 reads B/w.bin but allows only A (the link's target folder); 1.20 reads
    B/w.bin whatever it is. Data must resolve into both: a link within A runs, a copy in B is
    refused (the same on every version), a missing B/w.bin is 'not found' there."""
    real = save_external(tmp_path / "A")
    (tmp_path / "B").mkdir()
    os.symlink(real, tmp_path / "B" / "m.onnx")
    with pytest.raises(InputError, match=r"'w\.bin' not found in .*B"):
        check_external_data(tmp_path / "B" / "m.onnx")
    (tmp_path / "B" / "w.bin").write_bytes((tmp_path / "A" / "w.bin").read_bytes())
    with pytest.raises(InputError, match=r"the model file links there.*keep the model and"):
        Denoiser(tmp_path / "B" / "m.onnx", fast_kernels=False)
    os.symlink(real, tmp_path / "A" / "alias.onnx")
    assert check_external_data(tmp_path / "A" / "alias.onnx") == [(tmp_path / "A" / "w.bin")]
    Denoiser(tmp_path / "A" / "alias.onnx", fast_kernels=False)
