"""Tests of the HDR colour MLP (m4dgs.model.color) against a numpy reference."""

import numpy as np
import torch

from m4dgs.model.color import ColorMLP, view_directions


def _numpy_reference(mlp: ColorMLP, feat: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    w1 = mlp.fc1.weight.detach().double().numpy()
    b1 = mlp.fc1.bias.detach().double().numpy()
    w2 = mlp.fc2.weight.detach().double().numpy()
    b2 = mlp.fc2.bias.detach().double().numpy()
    x = np.concatenate([feat, dirs], axis=-1)
    h = np.maximum(x @ w1.T + b1, 0.0)
    return 2.0 ** (h @ w2.T + b2)


def test_shapes_values_and_positivity():
    torch.manual_seed(0)
    mlp = ColorMLP()
    assert mlp.fc1.in_features == 39 and mlp.fc1.out_features == 36 and mlp.fc2.out_features == 3
    feat = torch.randn(50, 36) * 5
    dirs = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    out = mlp(feat, dirs)
    assert out.shape == (50, 3)
    assert (out > 0).all()
    np.testing.assert_allclose(
        out.detach().numpy(),
        _numpy_reference(mlp, feat.double().numpy(), dirs.double().numpy()),
        rtol=1e-5,
    )
    assert mlp(torch.randn(2, 7, 36)).shape == (2, 7, 3)


def test_view_independent_mode_uses_zero_direction():
    torch.manual_seed(1)
    mlp = ColorMLP(view_dependent=False)
    feat = torch.randn(10, 36)
    dirs = torch.nn.functional.normalize(torch.randn(10, 3), dim=-1)
    torch.testing.assert_close(mlp(feat, dirs), mlp(feat))
    np.testing.assert_allclose(
        mlp(feat).detach().numpy(),
        _numpy_reference(mlp, feat.double().numpy(), np.zeros((10, 3))),
        rtol=1e-5,
    )


def test_clamp_and_view_directions():
    mlp = ColorMLP(max_log2=2.0)
    with torch.no_grad():
        mlp.fc2.bias.fill_(10.0)
    assert torch.allclose(mlp(torch.zeros(3, 36)), torch.full((3, 3), 4.0))
    d = view_directions(torch.tensor([[0.0, 0.0, 5.0], [3.0, 4.0, 0.0]]), torch.zeros(3))
    torch.testing.assert_close(d, torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]]))
