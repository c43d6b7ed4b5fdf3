"""Tests of the HDR colour MLP (m4dgs.model.color) against a numpy reference."""

import numpy as np
import pytest
import torch

from m4dgs.model.color import ColorMLP, view_directions
from m4dgs.raster.gsplat_backend import gsplat_available


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


class _StaticGaussians:
    """Minimal Gaussian set for render_gaussians: fixed means, no motion."""

    def __init__(self, means, feats):
        self.means, self.feats = means, feats

    def positions(self, t):
        return self.means if not torch.is_tensor(t) or t.dim() == 0 else self.means[:, None]

    def quats(self, t):
        return torch.tensor([1.0, 0.0, 0.0, 0.0]).expand(self.means.shape[0], 4)

    def scales(self):
        return torch.full_like(self.means, 0.3)

    def opacities(self):
        return torch.full((self.means.shape[0],), 0.8)

    def features(self):
        return self.feats


def test_view_direction_reaches_the_colour_mlp_of_pinhole_renders_only():
    """render_gaussians with a view-dependent MLP equals the rasterizer fed with colours computed
    from numpy directions (camera centre -> Gaussian); the orthographic camera gives zeros."""
    from m4dgs.core.camera import K_from_fov
    from m4dgs.model.background import Background
    from m4dgs.model.render import render_gaussians
    from m4dgs.raster import render

    torch.manual_seed(0)
    means = torch.tensor([[-0.5, 0.1, 3.0], [0.6, -0.2, 4.0], [0.0, 0.3, 5.0]])
    feats = torch.randn(3, 36)
    g = _StaticGaussians(means, feats)
    mlp, bg = ColorMLP(view_dependent=True), Background(False)
    K = torch.as_tensor(K_from_fov(48, 32, 60.0), dtype=torch.float32)
    c2w = torch.eye(4)
    c2w[:3, 3] = torch.tensor([0.2, -0.1, -1.0])
    with torch.no_grad():
        out = render_gaussians(g, mlp, bg, 0.0, c2w, K, 48, 32, "pinhole", "torch")
        d = means.numpy() - c2w[:3, 3].numpy()
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        colors = torch.from_numpy(_numpy_reference(mlp, feats.double().numpy(), d)).float()
        w2c = torch.linalg.inv(c2w)
        ref = render(
            means, g.quats(0), g.scales(), g.opacities(), colors, w2c, K, 48, 32,
            backend="torch", background=bg(),
        )  # fmt: skip
        torch.testing.assert_close(out.hdr, ref.features, rtol=1e-5, atol=1e-6)
        # off: the same render with zero directions differs
        mlp.view_dependent = False
        off = render_gaussians(g, mlp, bg, 0.0, c2w, K, 48, 32, "pinhole", "torch")
        assert (off.hdr - out.hdr).abs().max() > 1e-3
        # orthographic video camera: zeros even when view dependent
        mlp.view_dependent = True
        Ko = torch.tensor([[24.0, 0, 24.0], [0, 16.0, 16.0], [0, 0, 1.0]])
        a = render_gaussians(g, mlp, bg, 0.0, torch.eye(4), Ko, 48, 32, "ortho", "torch")
        mlp.view_dependent = False
        b = render_gaussians(g, mlp, bg, 0.0, torch.eye(4), Ko, 48, 32, "ortho", "torch")
        torch.testing.assert_close(a.hdr, b.hdr)


def _axis_angle_quat(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def test_normals_are_the_smallest_scale_axis():
    """A rotation of 90 degrees about z takes local x to world y and local y to world -x: the
    normal of a Gaussian flattest along local x is world +-y, along y +-x, along z +-z."""
    from m4dgs.model.color import gaussian_normals

    q = torch.tensor(np.stack([_axis_angle_quat([0, 0, 1], np.pi / 2)] * 3), dtype=torch.float64)
    scales = torch.tensor([[0.01, 1.0, 2.0], [1.0, 0.02, 2.0], [1.0, 2.0, 0.03]], dtype=q.dtype)
    n = gaussian_normals(q, scales)
    expect = torch.tensor([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=q.dtype)
    torch.testing.assert_close(n.abs(), expect.abs(), atol=1e-12, rtol=0)
    torch.testing.assert_close(n, expect, atol=1e-12, rtol=0)
    # a non-unit quaternion gives the same normal
    torch.testing.assert_close(gaussian_normals(3.0 * q, scales), n)


def test_reflect_is_a_mirror():
    """Mirroring about the plane z = 0 flips z; either sign of the normal; twice is identity;
    lengths are kept; a random case against the Householder matrix I - 2 n n^T."""
    from m4dgs.model.color import reflect

    d = torch.tensor([[0.6, 0.0, -0.8], [0.0, 1.0, 0.0]])
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    torch.testing.assert_close(reflect(d, n), torch.tensor([[0.6, 0.0, 0.8], [0.0, 1.0, 0.0]]))
    g = torch.Generator().manual_seed(3)
    d = torch.randn(20, 3, generator=g, dtype=torch.float64)
    n = torch.nn.functional.normalize(torch.randn(20, 3, generator=g, dtype=torch.float64), dim=-1)
    r = reflect(d, n)
    torch.testing.assert_close(reflect(d, -n), r)
    torch.testing.assert_close(reflect(r, n), d)
    torch.testing.assert_close(r.norm(dim=-1), d.norm(dim=-1))
    H = torch.eye(3, dtype=d.dtype) - 2 * n[:, :, None] * n[:, None, :]
    torch.testing.assert_close(r, (H @ d[:, :, None])[..., 0])


def test_reflected_direction_reaches_the_colour_mlp():
    """With direction "reflected" a pinhole render equals the rasterizer fed with colours of the
    numpy reflection of (camera centre -> Gaussian) about each Gaussian's smallest-scale axis; the
    colour then turns with the Gaussian (which "view" does not), and its gradient reaches the
    rotation (checked against a central finite difference)."""
    from m4dgs.core.camera import K_from_fov, quat_to_rotmat
    from m4dgs.model.background import Background
    from m4dgs.model.color import color_directions
    from m4dgs.model.render import render_gaussians
    from m4dgs.raster import render

    class _Turned(_StaticGaussians):
        def __init__(self, means, feats, q, s):
            super().__init__(means, feats)
            self.q, self.s = q, s

        def quats(self, t):
            return self.q

        def scales(self):
            return self.s

    torch.manual_seed(0)
    means = torch.tensor([[-0.5, 0.1, 3.0], [0.6, -0.2, 4.0], [0.0, 0.3, 5.0]])
    feats = torch.randn(3, 36)
    rng = np.random.default_rng(5)
    q = torch.tensor(rng.normal(size=(3, 4)), dtype=torch.float32)
    s = torch.tensor([[0.3, 0.05, 0.2], [0.02, 0.3, 0.25], [0.3, 0.2, 0.04]])
    g = _Turned(means, feats, q, s)
    mlp, bg = ColorMLP(view_dependent=True, direction="reflected"), Background(False)
    K = torch.as_tensor(K_from_fov(48, 32, 60.0), dtype=torch.float32)
    c2w = torch.eye(4)
    c2w[:3, 3] = torch.tensor([0.2, -0.1, -1.0])
    with torch.no_grad():
        out = render_gaussians(g, mlp, bg, 0.0, c2w, K, 48, 32, "pinhole", "torch")
        d = means.double().numpy() - c2w[:3, 3].double().numpy()
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        R = quat_to_rotmat(q.double()).numpy()
        n = np.stack([R[i][:, int(np.argmin(s[i].numpy()))] for i in range(3)])
        r = d - 2 * (d * n).sum(1, keepdims=True) * n
        colors = torch.from_numpy(_numpy_reference(mlp, feats.double().numpy(), r)).float()
        ref = render(
            means, q, s, g.opacities(), colors, torch.linalg.inv(c2w), K, 48, 32,
            backend="torch", background=bg(),
        )  # fmt: skip
        torch.testing.assert_close(out.hdr, ref.features, rtol=1e-5, atol=1e-6)
        # "view" on the same Gaussians gives other colours
        mlp.direction = "view"
        view = render_gaussians(g, mlp, bg, 0.0, c2w, K, 48, 32, "pinhole", "torch")
        assert (view.hdr - out.hdr).abs().max() > 1e-3
        mlp.direction = "reflected"

    # gradient of one Gaussian's colour with respect to its quaternion: autograd against a
    # central finite difference in float64
    mlp64 = ColorMLP(view_dependent=True, direction="reflected").double()
    mlp64.load_state_dict({k: v.double() for k, v in mlp.state_dict().items()})
    m64, s64, f64 = means.double(), s.double(), feats.double()
    cam = c2w[:3, 3].double()

    def colour_sum(qq):
        return mlp64(f64, color_directions(mlp64, m64, qq, s64, cam)).sum()

    q64 = q.double().clone().requires_grad_(True)
    colour_sum(q64).backward()
    num = torch.zeros_like(q64)
    eps = 1e-6
    with torch.no_grad():
        for i in range(3):
            for j in range(4):
                e = torch.zeros_like(q64)
                e[i, j] = eps
                num[i, j] = (colour_sum(q64 + e) - colour_sum(q64 - e)) / (2 * eps)
    assert num.abs().max() > 1e-3
    torch.testing.assert_close(q64.grad, num, rtol=1e-5, atol=1e-7)


def test_colour_direction_names_are_checked():
    with pytest.raises(ValueError, match="reflected"):
        ColorMLP(direction="mirror")


def test_specular_lobe_against_its_formula():
    """The lobe a exp(kappa (d . mu - 1)) from a numpy evaluation of the head; its start (amplitude
    2^SPEC_LOG2_AMPLITUDE0, sharpness SPEC_SHARPNESS0); its peak a along mu; added only where a
    direction is given."""
    from m4dgs.model.color import SPEC_LOG2_AMPLITUDE0, SPEC_SHARPNESS0

    torch.manual_seed(2)
    mlp = ColorMLP(view_dependent=True, direction="reflected", specular=True).double()
    feat = torch.randn(40, 36, dtype=torch.float64)
    dirs = torch.nn.functional.normalize(torch.randn(40, 3, dtype=torch.float64), dim=-1)
    with torch.no_grad():
        mlp.spec.weight.normal_(0.0, 0.3)  # away from the start: every row in play
        mlp.spec.bias.normal_(0.0, 0.3)
        lobe = mlp.specular_lobe(feat, dirs)
        full = mlp(feat, dirs)
    w, b = mlp.spec.weight.detach().numpy(), mlp.spec.bias.detach().numpy()
    out = feat.numpy() @ w.T + b
    mu = out[:, 3:6] / np.linalg.norm(out[:, 3:6], axis=1, keepdims=True)
    ref = 2.0 ** out[:, :3] * np.exp(
        np.exp(out[:, 6:]) * ((dirs.numpy() * mu).sum(1, keepdims=True) - 1)
    )
    np.testing.assert_allclose(lobe.numpy(), ref, rtol=1e-12)
    base = _numpy_reference(mlp, feat.numpy(), dirs.numpy())
    np.testing.assert_allclose(full.numpy(), base + ref, rtol=1e-12)
    # along its own axis a Gaussian shows the amplitude itself
    with torch.no_grad():
        np.testing.assert_allclose(
            mlp.specular_lobe(feat, torch.from_numpy(mu)).numpy(), 2.0 ** out[:, :3], rtol=1e-12
        )
    # no direction (stage 1's orthographic camera), or not view dependent: no lobe
    torch.testing.assert_close(
        mlp(feat), torch.from_numpy(_numpy_reference(mlp, feat.numpy(), np.zeros((40, 3))))
    )
    mlp.view_dependent = False
    torch.testing.assert_close(mlp(feat, dirs), mlp(feat))
    # the start: a feature of zeros gives the constants; every output depends on the feature
    fresh = ColorMLP(view_dependent=True, specular=True)
    o = fresh.spec(torch.zeros(1, 36))
    torch.testing.assert_close(o[0, :3], torch.full((3,), SPEC_LOG2_AMPLITUDE0))
    torch.testing.assert_close(o[0, 6], torch.tensor(float(np.log(SPEC_SHARPNESS0))))
    f = torch.randn(5, 36, requires_grad=True)
    out = fresh.spec(f)
    for k in range(7):
        (g,) = torch.autograd.grad(out[:, k].sum(), f, retain_graph=True)
        assert g.abs().min() > 0, k


class _LeafGaussians:
    """Gaussian set of leaf tensors (means, quats, scales, opacities, features), for gradients."""

    def __init__(self, tensors):
        self.means, self.q, self.s, self.o, self.feats = tensors

    def positions(self, t):
        return self.means

    def quats(self, t):
        return self.q

    def scales(self):
        return self.s

    def opacities(self):
        return self.o

    def features(self):
        return self.feats


@pytest.mark.gpu
@pytest.mark.skipif(not gsplat_available(), reason="needs CUDA and gsplat")
def test_reflected_specular_render_on_cuda_matches_the_cpu():
    """The reflected direction and the lobe on CUDA through gsplat give the values and gradients
    (Gaussians' parameters and the MLP's weights) of the torch rasterizer on the CPU."""
    from m4dgs.core.camera import K_from_fov
    from m4dgs.model.background import Background
    from m4dgs.model.render import render_gaussians

    W, H, n = 96, 64, 400
    g = torch.Generator().manual_seed(3)
    z = torch.rand(n, generator=g) * 3 + 3
    xy = (torch.rand(n, 2, generator=g) - 0.5) * z[:, None] * 1.2
    scene = [
        torch.cat([xy, z[:, None]], 1),
        torch.randn(n, 4, generator=g),
        torch.exp(torch.randn(n, 3, generator=g) * 0.5) * 0.05,
        torch.rand(n, generator=g) * 0.8 + 0.1,
        torch.randn(n, 36, generator=g) * 0.5,
    ]
    torch.manual_seed(0)
    mlp = ColorMLP(view_dependent=True, direction="reflected", specular=True)
    with torch.no_grad():
        mlp.spec.bias[:3] += 3.0  # bright lobes, so that they weigh in the render
    K = torch.as_tensor(K_from_fov(W, H, 60.0), dtype=torch.float32)
    c2w = torch.eye(4)
    c2w[:3, 3] = torch.tensor([0.3, -0.2, -0.5])
    w = torch.rand(H, W, 3, generator=g)

    def run(device, backend):
        leaves = [x.to(device).clone().requires_grad_(True) for x in scene]
        m = ColorMLP(view_dependent=True, direction="reflected", specular=True).to(device)
        m.load_state_dict(mlp.state_dict())
        out = render_gaussians(
            _LeafGaussians(leaves), m, Background(False).to(device), 0.0, c2w.to(device),
            K.to(device), W, H, "pinhole", backend,
        )  # fmt: skip
        (out.hdr * w.to(device)).sum().backward()
        grads = [x.grad.cpu() for x in leaves] + [p.grad.cpu() for p in m.parameters()]
        return out.hdr.detach().cpu(), grads

    hdr_g, grads_g = run("cuda", "gsplat")
    hdr_c, grads_c = run("cpu", "torch")
    assert hdr_c.max() > 1.0  # the lobes show
    err = (hdr_g - hdr_c).abs() / hdr_c.abs().clamp_min(1e-3)
    assert (err > 1e-3).float().mean() < 1e-3 and err.max() < 5e-2
    names = ["means", "quats", "scales", "opacities", "features"]
    names += [k for k, _ in mlp.named_parameters()]
    for name, a, b in zip(names, grads_g, grads_c):
        rel = ((a - b).norm() / b.norm()).item()
        assert b.norm() > 0 and rel < 1e-2, f"{name}: relative gradient difference {rel:.2e}"
