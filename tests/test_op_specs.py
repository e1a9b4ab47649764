"""Every op declared in rtdenoise.ops has its three forms, and they agree, checked generically
from the spec alone (a new op gets these tests without editing this file): torch reference ==
ONNX function body (ORT portable) == fast kernel (through ORT and called directly) on the spec's
example inputs for each example shape and attribute set; the ONNX schema, function and fast
kernel declaration match the spec; the torch custom op's fake gives the real output shapes;
calls that break the spec fail with a ValueError in the torch and fast forms."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from op_forms import RTOL, all_forms, assert_forms_agree, rel_err

from rtdenoise.export import ops as eops
from rtdenoise.models.ops import TORCH_OPS, exporting
from rtdenoise.ops import SPECS, Arg, OpSpec, snake_case
from rtdenoise.runtime import bridge as fast_bridge
from rtdenoise.runtime.bridge import extensions
from rtdenoise.runtime.kernels import KERNELS

CASES = [
    (name, shape, dict(attrs))
    for name, spec in sorted(SPECS.items())
    for attrs in spec.attr_sets()
    for shape in spec.example_shapes
]


def _id(case) -> str:
    name, shape, attrs = case
    return f"{name}-{'x'.join(map(str, shape))}-" + "-".join(f"{v}" for v in attrs.values())


def test_every_spec_has_all_three_forms():
    assert SPECS, "no op specs found"
    assert set(TORCH_OPS) == set(SPECS), "torch forms"
    assert set(eops.ONNX_FORMS) == set(SPECS), "ONNX function bodies"
    assert set(KERNELS) == set(SPECS) == set(extensions.FAST_OPS), "fast kernels"


@pytest.mark.parametrize("case", CASES, ids=[_id(c) for c in CASES])
def test_forms_agree_on_example_inputs(case):
    name, shape, attrs = case
    spec = SPECS[name]
    inputs = spec.example_inputs(shape, attrs, np.random.default_rng(sum(shape)))
    spec.validate_call([x.shape for x in inputs], attrs)
    outs = all_forms(name, inputs, attrs)
    assert_forms_agree(outs)
    expected = spec.output_shapes([x.shape for x in inputs], attrs)[0]
    assert outs["torch"].shape == tuple(expected)


OPTIONAL = sorted(name for name, spec in SPECS.items() if spec.optional_attrs)


@pytest.mark.parametrize("name", OPTIONAL)
def test_a_node_without_its_optional_attributes_runs_as_before(name):
    """A node exported before an attribute existed (the spec's optional_attrs omitted) runs on
    every path as the torch form with their values: the native bridges and the function body
    fill them in; onnxruntime-extensions refuses a node without a declared attribute, so the
    runtime writes them out before loading a model on that bridge
    (`fill_optional_attributes`, which `open_session` calls there)."""
    from rtdenoise.runtime.bridge import native_cpp
    from rtdenoise.runtime.static_check import fill_optional_attributes

    spec = SPECS[name]
    attrs = {**spec.default_attrs, **spec.optional_attrs}
    inputs = spec.example_inputs((1, 3, 16, 24), attrs, np.random.default_rng(5))
    feed = dict(zip(spec.input_names, inputs, strict=True))
    with torch.no_grad():
        want = TORCH_OPS[name].reference(*[torch.from_numpy(x) for x in inputs], **attrs)
    want = [t.numpy() for t in (want if isinstance(want, tuple | list) else (want,))]
    bridges = ["", "native", "extensions"]
    bridges += ["native-cpp"] if name in native_cpp.covered_ops() else []
    for b in bridges:
        model = eops.single_op_model(name, None, attrs, with_function=b != "native-cpp")
        (node,) = model.graph.node
        kept = [a for a in node.attribute if a.name not in spec.optional_attrs]
        del node.attribute[:]
        node.attribute.extend(kept)
        data = model.SerializeToString()
        filled = fill_optional_attributes(data)
        assert filled is not None and fill_optional_attributes(filled) is None
        (node,) = onnx.load_from_string(filled).graph.node
        assert {a.name: a.i for a in node.attribute} == attrs
        so = ort.SessionOptions()
        if b:
            assert fast_bridge.register_fast_kernels(so, b, [name]) == b
        sess = ort.InferenceSession(filled if b == "extensions" else data, so)
        before = fast_bridge.CALLS[name]
        outs = sess.run(None, feed)
        assert fast_bridge.CALLS[name] - before == (1 if b in ("native", "extensions") else 0), b
        for got, ref in zip(outs, want, strict=True):
            assert rel_err(got, ref) <= RTOL, (b or "portable", rel_err(got, ref))


@pytest.mark.parametrize("name", sorted(SPECS))
def test_onnx_form_matches_spec(name):
    spec = SPECS[name]
    form = eops.ONNX_FORMS[name]
    assert [p.name for p in form.schema.inputs] == list(spec.input_names)
    assert [p.name for p in form.schema.outputs] == list(spec.output_names)
    assert sorted(form.schema.attributes) == sorted(spec.attrs)
    model = eops.single_op_model(name, None, dict(spec.default_attrs))
    onnx.checker.check_model(model, full_check=True)
    (func,) = model.functions
    assert (func.domain, func.name) == ("rtdenoise", name)
    assert list(func.input) == list(spec.input_names)
    assert list(func.output) == list(spec.output_names)
    # an optional attribute (spec.optional_attrs) is an attribute_proto carrying its value
    required = [a for a in spec.attrs if a not in spec.optional_attrs]
    assert list(func.attribute) == required
    assert {a.name: a.i for a in func.attribute_proto} == dict(spec.optional_attrs)
    assert {a for a, s in form.schema.attributes.items() if s.required} == set(required)
    assert all(n.domain in ("", "ai.onnx") for n in func.node)  # standard ops only
    (node,) = model.graph.node
    assert {a.name for a in node.attribute} == set(spec.attrs)


@pytest.mark.parametrize("name", sorted(SPECS))
def test_model_without_function_runs_only_with_the_fast_kernel(name):
    spec = SPECS[name]
    attrs = dict(spec.default_attrs)
    inputs = spec.example_inputs(spec.example_shapes[0], attrs, np.random.default_rng(0))
    model = eops.single_op_model(name, [x.shape for x in inputs], attrs, with_function=False)
    assert len(model.functions) == 0
    with pytest.raises(Exception, match=name):
        ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    so = ort.SessionOptions()
    fast_bridge.register_fast_kernels(so)
    sess = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
    before = fast_bridge.CALLS[name]
    outs = sess.run(None, dict(zip(spec.input_names, inputs, strict=True)))
    assert fast_bridge.CALLS[name] == before + 1 and len(outs) == len(spec.outputs)
    with torch.no_grad():
        ref = TORCH_OPS[name].reference(*[torch.from_numpy(x) for x in inputs], **attrs)
    refs = ref if isinstance(ref, tuple) else (ref,)
    for out, r in zip(outs, refs, strict=True):
        assert rel_err(out, r.numpy()) <= RTOL


@pytest.mark.parametrize("name", sorted(SPECS))
def test_custom_op_fake_and_eager_agree_with_reference(name):
    """The export-mode custom op: its fake (spec shape rule) and its eager values."""
    spec = SPECS[name]
    attrs = dict(spec.default_attrs)
    inputs = spec.example_inputs(spec.example_shapes[0], attrs, np.random.default_rng(1))
    tensors = [torch.from_numpy(x) for x in inputs]
    op = TORCH_OPS[name]
    assert op.overload() is getattr(torch.ops.rtdenoise, snake_case(name)).default
    with exporting():
        custom = op(*tensors, **attrs)
    plain = op(*tensors, **attrs)
    customs = custom if isinstance(custom, tuple) else (custom,)
    plains = plain if isinstance(plain, tuple) else (plain,)
    with torch._subclasses.fake_tensor.FakeTensorMode() as mode:
        fakes = [mode.from_tensor(t) for t in tensors]
        fake = op.custom(*fakes, *(attrs[a] for a in spec.attrs))
    fakes_out = fake if isinstance(fake, tuple) else (fake,)
    for c, p, f in zip(customs, plains, fakes_out, strict=True):
        assert torch.allclose(c, p, atol=1e-6)
        assert tuple(f.shape) == tuple(p.shape)


@pytest.mark.parametrize("name", sorted(SPECS))
def test_calls_that_break_the_spec_are_refused(name):
    spec = SPECS[name]
    attrs = dict(spec.default_attrs)
    inputs = spec.example_inputs(spec.example_shapes[0], attrs, np.random.default_rng(2))
    squeezed = [inputs[0][0], *inputs[1:]]  # first input one rank short
    with pytest.raises(ValueError, match=f"{name}: {spec.inputs[0].name} must be"):
        KERNELS[name](*squeezed, **attrs)
    with pytest.raises(ValueError, match=f"{name}: {spec.inputs[0].name} must be"):
        TORCH_OPS[name](*[torch.from_numpy(x) for x in squeezed], **attrs)
    with pytest.raises(ValueError, match=f"{name} takes {len(spec.inputs)} inputs"):
        KERNELS[name](*inputs[:-1], **attrs)
    with pytest.raises(ValueError, match="attributes"):
        KERNELS[name](*inputs, **attrs, bogus=1)


def test_spec_rejects_default_attrs_that_do_not_match():
    with pytest.raises(ValueError, match="default_attrs"):
        OpSpec(
            name="Broken",
            doc="",
            inputs=(Arg("x"),),
            outputs=(Arg("y"),),
            attrs=("k",),
            output_shapes=lambda shapes, attrs: [shapes[0]],
            example_inputs=lambda shape, attrs, rng: [],
        )
    assert snake_case("WeightSharingFilter") == "weight_sharing_filter"
