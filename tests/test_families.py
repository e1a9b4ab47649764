"""The contract every registered family keeps, checked on each in its `example_config` (a new
family joins without editing this file): shapes and range, reset semantics, gradients,
checkpoint round-trip. Family-specific behaviour stays in tests/test_<family>_model.py."""

from __future__ import annotations

import pytest
import torch
from model_inputs import random_buffers, samples_of

from rtdenoise.models.checkpoint import load_checkpoint, save_checkpoint
from rtdenoise.models.registry import build_model, families, family_class

# family -> its small config for fast tests
SMALL = {name: family_class(name).example_config for name in families()}
N, H, W = 2, 32, 24


def test_families_are_found():
    assert {"afn", "wskp"} <= set(SMALL)
    with pytest.raises(ValueError, match="unknown model family 'nope'; known: \\[.*'afn'"):
        build_model("nope")


def _buffers(model, seed: int, n: int = N, h: int = H, w: int = W) -> dict[str, torch.Tensor]:
    return {k: v for k, v in random_buffers(seed, n, h, w).items() if k in model.inputs}


@pytest.fixture(scope="module", params=sorted(SMALL))
def model(request):
    torch.manual_seed(0)
    return build_model(request.param, SMALL[request.param]).eval().requires_grad_(False)


def test_forward_shapes_state_and_range(model):
    assert H % model.pad_multiple == 0 and W % model.pad_multiple == 0
    out, nxt = model(_buffers(model, 0), model.initial_state(N, H, W), torch.tensor(1.0))
    assert out.shape == (N, 3, H, W)
    assert set(nxt) == {s.name for s in model.state_specs}
    for spec in model.state_specs:
        assert nxt[spec.name].shape == (N, spec.channels, *spec.spatial(H, W))
    assert torch.isfinite(out).all() and float(out.min()) >= 0.0
    # extreme but legal inputs: fireflies, zero albedo, background depth, zero normals
    b = random_buffers(1, N, H, W)
    b["color"][:, :, :4] = 1e4
    b["albedo"][:, :, 4:8] = 0.0
    b["depth"][:, :, 8:12] = 1e4
    b["normal"][:, :, 12:16] = 0.0
    b["samples"] = samples_of(b)
    b = {k: v for k, v in b.items() if k in model.inputs}
    out2, nxt2 = model(b, nxt, torch.tensor(0.0))
    assert torch.isfinite(out2).all() and float(out2.min()) >= 0.0
    assert all(torch.isfinite(v).all() for v in nxt2.values())


def test_next_state_holds_accumulation_and_geometry(model):
    if {s.name for s in model.state_specs} != {"ta", "geometry"}:
        pytest.skip("family keeps other state")
    b = _buffers(model, 2)
    _, nxt = model(b, model.initial_state(N, H, W), torch.tensor(1.0))
    irradiance = b["color"] / (b["albedo"] + model.cfg.albedo_eps)
    torch.testing.assert_close(nxt["ta"][:, :3], irradiance)  # reset: TA = current frame
    torch.testing.assert_close(nxt["ta"][:, 3:], torch.ones(N, 1, H, W))  # history length 1
    torch.testing.assert_close(nxt["geometry"], torch.cat((b["normal"], b["depth"]), dim=1))


def test_reset_ignores_state_values(model):
    b = _buffers(model, 3)
    g = torch.Generator().manual_seed(9)
    s1 = {k: torch.rand(v.shape, generator=g) * 10 for k, v in model.initial_state(N, H, W).items()}
    s2 = {k: torch.rand(v.shape, generator=g) for k, v in model.initial_state(N, H, W).items()}
    # an online model's control states (rtdenoise.online "controls") are host inputs, read
    # even with reset = 1 (docs/contract.md): give both calls the default (0)
    controls = set((model.declaration().online or {}).get("controls", []))
    for name in controls:
        s1[name] = s2[name] = torch.zeros_like(s1[name])
    o1, n1 = model(b, s1, torch.tensor(1.0))
    o2, n2 = model(b, s2, torch.tensor(1.0))
    torch.testing.assert_close(o1, o2, atol=0, rtol=0)
    for k in n1:
        torch.testing.assert_close(n1[k], n2[k], atol=0, rtol=0)
    # without reset, a valid history changes the result (the state is really used)
    static = dict(b, motion=torch.zeros(N, 2, H, W))
    _, warm = model(static, s1, torch.tensor(1.0))
    # brighter history (and other learned state), same geometry: still valid
    keep = {"geometry", *controls}
    warm = {k: v if k in keep else v * 3.0 + 1.0 for k, v in warm.items()}
    o3, _ = model(static, warm, torch.tensor(0.0))
    o4, _ = model(static, warm, torch.tensor(1.0))
    assert float((o3 - o4).abs().max()) > 1e-3


@pytest.mark.parametrize("family", sorted(SMALL))
def test_gradients_reach_every_parameter(family):
    torch.manual_seed(1)
    m = build_model(family, SMALL[family]).train()
    state = m.initial_state(N, H, W)
    out, state = m(_buffers(m, 4), state, torch.tensor(1.0))
    out2, _ = m(_buffers(m, 5), state, torch.tensor(0.0))
    (out.mean() + out2.mean()).backward()
    missing = [n for n, p in m.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert missing == [] and len(list(m.parameters())) > 0


def test_config_roundtrip_through_checkpoint(tmp_path, model):
    path = save_checkpoint(tmp_path / f"{model.family}.pt", model, {"note": "test"})
    loaded, meta = load_checkpoint(path)
    assert type(loaded) is type(model) and meta == {"note": "test"}
    assert loaded.config() == model.config() == type(model)(model.config()).config()
    b = _buffers(model, 6)
    state = model.initial_state(N, H, W)
    with torch.no_grad():
        ref, ref_state = model(b, state, torch.tensor(1.0))
        out, out_state = loaded(b, state, torch.tensor(1.0))
    torch.testing.assert_close(out, ref, atol=0, rtol=0)
    for k in ref_state:
        torch.testing.assert_close(out_state[k], ref_state[k], atol=0, rtol=0)
