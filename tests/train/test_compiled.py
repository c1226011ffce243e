"""The SDF's gradient written out (one backward for a loss on the normals, so the query compiles),
and the compiled queries: the same numbers as eager, and eager again where compiling fails."""

import pytest
import torch

import srvol.compiled as compiled
from srvol.fields import FieldConfig, SceneFields
from srvol.compiled import COMPILE_MIN_ITERS, COMPILE_MIN_SECONDS, compile_training


def _busy_fields(activation: str, interpolation: str = "smoothstep") -> SceneFields:
    """A grid SDF far from its initial sphere: random grid features, a head with weight."""
    torch.manual_seed(0)
    fields = SceneFields(FieldConfig(sdf_levels=(8, 16, 32), sdf_hidden=32, activation=activation,
                                     sdf_interpolation=interpolation), learn_intensity=False)
    with torch.no_grad():
        fields.sdf_net.grids.table.normal_(0.0, 0.05)
        for layer in fields.sdf_net.head:
            if isinstance(layer, torch.nn.Linear):
                layer.weight.normal_(0.0, 0.3)
                layer.bias.normal_(0.0, 0.01)
        fields.sdf_net.grids.level_weights.copy_(torch.tensor([1.0, 0.7, 0.2]))  # mid coarse-to-fine
    return fields


def _autograd_normal_path(fields: SceneFields, x: torch.Tensor):
    """What autograd gives: d, and its x-gradient with the graph for a loss on it."""
    x = x.clone().requires_grad_(True)
    d = fields.sdf_net(x)
    (g,) = torch.autograd.grad(d.sum(), x, create_graph=True)
    return d, g


@pytest.mark.parametrize("activation,interpolation",
                         [("gelu", "smoothstep"), ("softplus", "smoothstep"), ("gelu", "bspline")])
def test_the_written_out_gradient_is_autograds_and_so_are_the_eikonal_terms_parameter_gradients(activation,
                                                                                              interpolation):
    fields = _busy_fields(activation, interpolation)
    x = torch.rand(3000, 3, generator=torch.Generator().manual_seed(1)) * 1.8 - 0.9
    d_ref, g_ref = _autograd_normal_path(fields, x)
    d, g = fields.sdf_net.value_and_gradient(x)  # the written-out path
    assert torch.allclose(d, d_ref, atol=1e-6)
    assert torch.allclose(g, g_ref, atol=1e-5 * float(g_ref.abs().max()))
    assert float(g_ref.norm(dim=-1).std()) > 0.3  # a busy field: the head and grids carry the gradient

    def eikonal_grads(d, g):
        loss = ((g.norm(dim=-1) - 1.0) ** 2).mean() + d.abs().mean()
        return torch.autograd.grad(loss, list(fields.sdf_net.parameters()))

    for ref, ours in zip(eikonal_grads(d_ref, g_ref), eikonal_grads(d, g)):
        assert torch.allclose(ours, ref, rtol=1e-4, atol=1e-5 * float(ref.abs().max()) + 1e-9)


def test_without_create_graph_the_gradient_is_detached_and_the_same():
    fields = _busy_fields("gelu")
    x = torch.rand(200, 3, generator=torch.Generator().manual_seed(3)) * 1.8 - 0.9
    _, g_ref = _autograd_normal_path(fields, x)
    assert not fields.sdf_net.writes_out_gradient(compiled=False)  # eagerly, autograd's (faster there)
    assert fields.sdf_net.writes_out_gradient(compiled=True)
    fields.sdf_net.explicit_gradient = True  # the compiled queries' path, without compiling
    _, g = fields.sdf_and_gradient(x, create_graph=False)
    assert not g.requires_grad and torch.allclose(g, g_ref.detach(), atol=1e-5 * float(g_ref.abs().max()))


def test_compiled_queries_give_eagers_numbers():
    fields = _busy_fields("gelu")
    x = torch.rand(700, 3, generator=torch.Generator().manual_seed(4)) * 1.8 - 0.9
    with torch.no_grad():
        d_ref = fields.sdf(x)
        fields.compile_queries()
        d = fields.sdf(x)
        d_view = fields.sdf(torch.cat([x, x]).reshape(2, 700, 3)[1])  # a view, as the samples along rays are
    assert fields._compiled.failed is None, fields._compiled.failed
    assert torch.allclose(d, d_ref, atol=1e-5) and torch.allclose(d_view, d_ref, atol=1e-5)


def test_a_failing_compiler_leaves_eager_queries_and_one_warning(monkeypatch, capsys):
    def broken_compile(fn, **_):
        def call(*args):
            raise RuntimeError("no C++ compiler found\nmore detail")
        return call

    monkeypatch.setattr(compiled.torch, "compile", broken_compile)
    fields = _busy_fields("gelu")
    x = torch.rand(300, 3, generator=torch.Generator().manual_seed(5)) * 1.8 - 0.9
    with torch.no_grad():
        d_ref = fields.sdf(x)
        fields.compile_queries()
        d = fields.sdf(x)
        m = fields.material(x)
        fields.sdf(x)
    assert torch.equal(d, d_ref) and m.albedo.shape == (300, 3)
    err = capsys.readouterr().err
    assert err.count("warning: compiled field queries unavailable") == 1
    assert "RuntimeError: no C++ compiler found" in err and "more detail" not in err


def test_compiling_is_on_for_runs_long_enough_to_repay_it():
    assert compile_training("auto", iters=0, time_budget=600.0)  # a 600 s run
    assert not compile_training("auto", iters=0, time_budget=COMPILE_MIN_SECONDS - 1)
    # a short fixed-iteration run: the budget is not what bounds it
    assert not compile_training("auto", iters=40, time_budget=600.0)
    assert compile_training("auto", iters=COMPILE_MIN_ITERS, time_budget=600.0)
    assert compile_training("on", iters=40, time_budget=0.0) and not compile_training("off", iters=0, time_budget=600.0)


def test_the_warm_up_before_each_stage_leaves_the_runs_draws_untouched(default_scene, tmp_path, monkeypatch):
    """A compiled run compiles with one throwaway step before each stage (off the schedule's clock);
    that step draws from its own generators, so the run takes the same steps as an uncompiled one
    (here the compiler is replaced by the eager queries: the warm-up itself is what is checked)."""
    from dataclasses import replace

    from srvol.data import load_scene
    from srvol.presets import auto_config
    from srvol.train import train

    monkeypatch.setattr(SceneFields, "compile_queries", lambda self: None)
    scene = load_scene(default_scene)
    base = replace(auto_config(scene, "gaussian", 60.0), iters=8, time_budget=0.0, checkpoint_every=10_000,
                   log_every=4, batch_in=64, batch_out=32, batch_eikonal=64, batch_stage2=64, stage2_fraction=0.5)
    weights = []
    for compile in (False, True):
        run = tmp_path / f"compile_{compile}"
        summary = train(scene, replace(base, compile=compile), run, progress=False, say=lambda *_: None)
        assert summary.iterations == 8
        weights.append(torch.load(run / "model.pt", weights_only=True))
    for name, value in weights[0].items():
        assert torch.equal(value, weights[1][name]), name
