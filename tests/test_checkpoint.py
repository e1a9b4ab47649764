"""Checkpoints: plain dicts loaded with weights_only=True; clear errors naming the file."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

import rtdenoise
from rtdenoise.models.checkpoint import (
    CheckpointError,
    load_checkpoint,
    load_training_state,
    read_checkpoint,
    save_checkpoint,
)
from rtdenoise.models.registry import build_model
from rtdenoise.runtime.errors import InputError

SMALL = {"widths": [8, 12], "kernel_size": 3, "refine_width": 8, "refine_layers": 2}


class Payload:
    """Stands for any object a malicious pickle could carry."""


@pytest.fixture()
def model():
    torch.manual_seed(0)
    return build_model("afn", SMALL)


def test_save_load_roundtrip_is_a_plain_dict(tmp_path, model):
    path = save_checkpoint(tmp_path / "m.pt", model, {"step": 3})
    raw = torch.load(path, weights_only=True)  # loads with no custom class allowed
    assert set(raw) == {"family", "config", "state_dict", "meta", "family_source"}
    assert raw["family_source"] == {
        "module": "rtdenoise.models.families.afn",
        "entry_point": "afn = rtdenoise.models.families.afn:AFN",
        "distribution": f"rtdenoise {rtdenoise.__version__}",
    }
    assert raw["family"] == "afn" and raw["config"]["widths"] == [8, 12]
    loaded, meta = load_checkpoint(path)
    assert meta == {"step": 3} and not loaded.training
    for k, v in model.state_dict().items():
        assert torch.equal(loaded.state_dict()[k], v)
    assert [p.name for p in tmp_path.iterdir()] == ["m.pt"]  # no temp file left behind


def test_overwrite_is_atomic_and_keeps_training_state(tmp_path, model):
    path = tmp_path / "m.pt"
    save_checkpoint(path, model, {"step": 1})
    save_checkpoint(path, model, {"step": 2}, train={"step": 2, "rng": {"x": [1, 2]}})
    m2, meta, train = load_training_state(path)
    assert meta["step"] == 2 and train == {"step": 2, "rng": {"x": [1, 2]}} and m2.training
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.pt"]
    save_checkpoint(path, model, {})
    with pytest.raises(CheckpointError, match="no training state"):
        load_training_state(path)


def test_not_a_checkpoint_names_the_file(tmp_path):
    text = tmp_path / "notes.txt"
    text.write_text("hello, I am not a checkpoint\n")
    with pytest.raises(CheckpointError, match=r"notes\.txt: not an rtdenoise checkpoint"):
        load_checkpoint(text)
    with pytest.raises(CheckpointError, match=r"missing\.pt: no such checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")
    other = tmp_path / "tensor.pt"
    torch.save(torch.zeros(3), other)
    with pytest.raises(CheckpointError, match=r"tensor\.pt: not an rtdenoise checkpoint"):
        load_checkpoint(other)
    assert issubclass(CheckpointError, InputError)


def test_pickled_objects_are_refused(tmp_path, model):
    """weights_only=True: a checkpoint smuggling an arbitrary object is rejected, not run."""
    path = tmp_path / "evil.pt"
    ckpt = {
        "family": "afn",
        "config": model.config(),
        "state_dict": model.state_dict(),
        "meta": {"obj": Payload()},  # a class weights_only does not allow
    }
    torch.save(ckpt, path)
    with pytest.raises(CheckpointError, match=r"evil\.pt: not an rtdenoise checkpoint"):
        read_checkpoint(path)
    with pytest.raises(CheckpointError, match=r"needs the Python object \S*Payload, refused") as e:
        load_checkpoint(path)  # the reason names the refused global ...
    assert "weights_only" not in str(e.value) and "\n" not in str(e.value)  # ... never the
    # library's advice to load with weights_only=False, which would run the file's code


def test_unknown_family_and_bad_state_dict(tmp_path, model):
    good = {
        "family": "afn",
        "config": model.config(),
        "state_dict": model.state_dict(),
        "meta": {},
    }
    path = tmp_path / "fam.pt"
    torch.save(dict(good, family="warp9"), path)
    with pytest.raises(
        CheckpointError,
        match=r"fam\.pt: model family 'warp9' is not registered "
        r"here; install the package that declares it .* --family-module <module>",
    ):
        load_checkpoint(path)
    source = {"module": "warp_pkg.net", "entry_point": None, "distribution": None}
    torch.save(dict(good, family="warp9", family_source=source), path)
    with pytest.raises(
        CheckpointError,
        match=r"\(it came from module warp_pkg\.net\); .* with "
        r"--family-module warp_pkg\.net; known: \['affinity'",
    ):
        load_checkpoint(path)
    torch.save(dict(good, config=dict(good["config"], bogus=1)), path)
    with pytest.raises(CheckpointError, match=r"fam\.pt: unknown afn config keys \['bogus'\]"):
        load_checkpoint(path)
    sd = dict(good["state_dict"])
    sd.pop(next(iter(sd)))
    torch.save(dict(good, state_dict=sd), path)
    with pytest.raises(CheckpointError, match=r"fam\.pt: state_dict does not match the afn"):
        load_checkpoint(path)
    wider = build_model("afn", dict(SMALL, widths=[8, 16])).state_dict()
    torch.save(dict(good, state_dict=wider), path)
    with pytest.raises(CheckpointError, match=r"fam\.pt: state_dict does not match"):
        load_checkpoint(path)


@pytest.mark.parametrize("family", ["afn", "wskp", "nbg"])
def test_checkpoints_without_the_reprojection_field_load_as_bilinear(family, tmp_path):
    """Checkpoints saved before AccumulatingConfig.reprojection existed load as "bilinear"
    (what they were trained with); the shipped demos load with the reprojection they record."""
    from pathlib import Path

    path = Path(rtdenoise.__file__).parent / "assets" / "models" / f"{family}.pt"
    shipped = read_checkpoint(path)
    loaded, _ = load_checkpoint(path)
    assert loaded.cfg.reprojection == shipped["config"].get("reprojection", "bilinear")
    old_config = {k: v for k, v in shipped["config"].items() if k != "reprojection"}
    old = tmp_path / f"{family}_old.pt"
    torch.save(dict(shipped, config=old_config), old)
    loaded, _ = load_checkpoint(old)
    assert loaded.cfg.reprojection == "bilinear" and loaded.cfg.temporal().per_tap == 0


def test_reprojection_round_trips_and_bad_values_are_refused(tmp_path):
    torch.manual_seed(0)
    model = build_model("afn", {**SMALL, "reprojection": "per_tap"})
    assert model.cfg.temporal().per_tap == 1
    loaded, _ = load_checkpoint(save_checkpoint(tmp_path / "m.pt", model, {}))
    assert loaded.cfg.reprojection == "per_tap" and loaded.config() == model.config()
    hdr = build_model("nbg", {"reprojection": "per_tap_hdr"})
    assert hdr.cfg.temporal().per_tap == 2
    loaded, _ = load_checkpoint(save_checkpoint(tmp_path / "hdr.pt", hdr, {}))
    assert loaded.cfg.temporal().per_tap == 2
    assert build_model("nbg", {"reprojection": "per_tap_hdr2"}).cfg.temporal().per_tap == 3
    match = "reprojection must be one of 'bilinear', 'per_tap', 'per_tap_hdr', 'per_tap_hdr2'"
    with pytest.raises(ValueError, match=match):
        build_model("wskp", {"reprojection": "nearest"})


def test_weight_average_is_the_weighted_mean_and_keeps_every_command(tmp_path, model):
    """scripts/average_checkpoints.py: 0.7 a + 0.3 b per float tensor, the sources' commands
    once each (oldest first) then its own; another config is refused, naming the file."""
    import runpy

    from rtdenoise.models.weight_average import average_checkpoints

    a = save_checkpoint(tmp_path / "a.pt", model, {"commands": ["train a"]})
    torch.manual_seed(1)
    other = build_model("afn", SMALL)
    b = save_checkpoint(tmp_path / "b.pt", other, {"commands": ["train a", "fine-tune b"]})
    script = Path(__file__).resolve().parents[1] / "scripts" / "average_checkpoints.py"
    main = runpy.run_path(str(script))["main"]
    out = tmp_path / "soup.pt"
    assert main([str(a), str(b), "--weights", "0.7", "0.3", "-o", str(out)]) == 0
    soup, meta = load_checkpoint(out)
    for key, value in soup.state_dict().items():
        if value.is_floating_point():
            want = 0.7 * model.state_dict()[key] + 0.3 * other.state_dict()[key]
            torch.testing.assert_close(value, want)
    assert meta["commands"][:2] == ["train a", "fine-tune b"]
    assert meta["commands"][2].startswith("python scripts/average_checkpoints.py")
    assert [s["weight"] for s in meta["averaged_from"]] == [0.7, 0.3]
    wider = save_checkpoint(tmp_path / "c.pt", build_model("afn", {**SMALL, "refine_width": 12}))
    with pytest.raises(CheckpointError, match="c.pt"):
        average_checkpoints([a, wider], [0.5, 0.5])
    with pytest.raises(ValueError, match="sum to 1"):
        average_checkpoints([a, b], [0.5, 0.6])
