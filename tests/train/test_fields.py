"""The grid fields' activation: a rounded ReLU with second derivatives, and old runs load as trained."""
import torch

from srvol.fields import FieldConfig, SceneFields, SharpGELU


def test_sharp_gelu_is_a_relu_rounded_over_a_hundredth():
    x = torch.linspace(-1.0, 1.0, 2001)
    y = SharpGELU()(x)
    assert float((y - torch.relu(x)).abs().max()) < 0.002
    assert float((y - torch.relu(x)).abs()[x.abs() > 0.05].max()) < 1e-6
    # like Softplus(beta=100), it has a second derivative at the kink (the eikonal's double backward)
    x0 = torch.zeros(1, requires_grad=True)
    (g,) = torch.autograd.grad(SharpGELU()(x0).sum(), x0, create_graph=True)
    (h,) = torch.autograd.grad(g.sum(), x0)
    assert abs(float(g.detach()) - 0.5) < 1e-6 and float(h) > 30.0


def test_a_config_saved_before_the_activation_choice_loads_with_softplus():
    saved = FieldConfig(activation="softplus").to_json()
    del saved["activation"]
    old = FieldConfig.from_json(saved)
    assert old.activation == "softplus"
    assert isinstance(SceneFields(old, learn_intensity=False).sdf_net.head[1], torch.nn.Softplus)
    assert isinstance(SceneFields(FieldConfig(), learn_intensity=False).sdf_net.head[1], SharpGELU)
