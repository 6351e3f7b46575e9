"""The repair input a second model makes (go_core.repair.consensus): what both renders share, and the repair
cache restoring it instead of the model's own render."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from go_core.gaussians import Gaussians
from go_core.repair.arcs import RepairArcs
from go_core.repair.consensus import agreed_render, colour_under
from go_core.repair.repair import RepairCache
from go_core.repair.settings import RepairSettings
from tests.test_repair_math import ring_cameras


def test_agreed_render_against_hand_values():
    # pixel 0: both opaque (red, blue); 1: only A (a fin); 2: A half, B a quarter; 3: neither
    colour_a = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0.2, 0.4, 0.6], [0.5, 0.5, 0.5]])
    colour_b = torch.tensor([[0, 0, 1.0], [0.3, 0.3, 0.3], [0.6, 0.4, 0.2], [0.5, 0.5, 0.5]])
    alpha_a = torch.tensor([1.0, 1.0, 0.5, 0.0])
    alpha_b = torch.tensor([1.0, 0.0, 0.25, 0.0])
    on_white = lambda c, a: c * a[:, None] + (1 - a[:, None])  # noqa: E731
    pair = [(on_white(colour_a, alpha_a), alpha_a), (on_white(colour_b, alpha_b), alpha_b)]
    rgb, alpha = agreed_render(pair)
    assert alpha.tolist() == [1.0, 0.0, 0.25, 0.0]
    mixed = (np.array([0.2, 0.4, 0.6]) * 0.5 + np.array([0.6, 0.4, 0.2]) * 0.25) / 0.75
    expected = [[0.5, 0.0, 0.5], [1.0, 1.0, 1.0], list(mixed * 0.25 + 0.75), [1.0, 1.0, 1.0]]
    np.testing.assert_allclose(rgb.numpy(), expected, atol=1e-6)
    np.testing.assert_allclose(
        colour_under(on_white(colour_a, alpha_a), alpha_a)[:3].numpy(), colour_a[:3], atol=1e-6
    )


def test_three_renders_agree_on_the_least_alpha_and_the_alpha_weighted_colour():
    """Three models: alpha is the smallest of the three, colour the mean weighted by each one's alpha (hand
    values); a third render that agrees with the first two leaves their agreement as it was."""
    colours = torch.tensor([[[0.9, 0.1, 0.1]], [[0.1, 0.9, 0.1]], [[0.1, 0.1, 0.9]]])  # [model, pixel, rgb]
    alphas = torch.tensor([[0.8], [0.4], [0.2]])
    renders = [(c * a[:, None] + (1 - a[:, None]), a) for c, a in zip(colours, alphas, strict=True)]
    rgb, alpha = agreed_render(renders)
    mixed = np.array([0.8, 0.4, 0.2]) @ colours[:, 0].double().numpy()
    expected = mixed / 1.4 * 0.2 + 0.8
    np.testing.assert_allclose(alpha.numpy(), [0.2], atol=1e-7)
    np.testing.assert_allclose(rgb.numpy(), [expected], atol=1e-6)
    two = agreed_render(renders[:2])
    both = agreed_render([*renders[:2], renders[0]])  # a copy of the opaque one: alpha stays 0.4
    torch.testing.assert_close(both[1], two[1])
    with pytest.raises(ValueError, match="two or more"):
        agreed_render(renders[:1])


def test_a_model_agrees_with_itself():
    rgb = torch.rand(6, 5, 3)
    alpha = torch.rand(6, 5) * 0.9 + 0.1
    on_white = rgb * alpha[..., None] + (1 - alpha[..., None])
    same, same_alpha = agreed_render([(on_white, alpha)] * 3)
    torch.testing.assert_close(same, on_white, atol=1e-6, rtol=0)
    torch.testing.assert_close(same_alpha, alpha)


class _Identity:
    """A repair model that returns its input: the cache then holds exactly what it was asked to restore."""

    channels = 3
    device = "cpu"

    @staticmethod
    def square_side(settings):
        return settings.compact_resolution

    def restore(self, square, rng, gen, settings):
        return square, 1000, 1.0


def _blob(z: float) -> Gaussians:
    """One opaque Gaussian at (0, 0, z), radius 0.3, grey."""
    return Gaussians.from_points(
        torch.tensor([[0.0, 0.0, z]]), torch.full((1, 3), 0.4), torch.tensor([0.3]), opacity=0.99, sh_degree=0
    )


@pytest.mark.parametrize("other_z, white", [(0.0, False), (40.0, True)])
def test_cache_restores_what_both_models_render(other_z, white):
    train = ring_cameras([0, 90, 180, 270])
    arcs = RepairArcs.from_cameras(train, keep=0.8)
    settings = RepairSettings(views_per_arc=1, compact_resolution=64)
    model = _blob(0.0)
    alone = RepairCache(arcs, _Identity(), settings, 0, None, 0).make(0, model)
    agreed = RepairCache(arcs, _Identity(), settings, 0, None, 0, consensus=[_blob(other_z)]).make(0, model)
    for a, b in zip(alone, agreed, strict=True):
        assert a.camera.name == b.camera.name
        if white:  # the second model is out of every view: nothing is agreed, the input is white
            assert a.image.min() < 0.6
            torch.testing.assert_close(b.image, torch.ones_like(b.image), atol=1e-3, rtol=0)
        else:  # the same model: the input is the model's own render
            torch.testing.assert_close(b.image, a.image, atol=1e-5, rtol=0)


class _WithAlpha(_Identity):
    channels = 4  # a repair prior's RGB + alpha


def test_a_restorer_without_alpha_gives_no_mask_target():
    """Under the consensus too, a view repaired by a restorer that gives no alpha has no mask target (the
    models' agreed alpha as one cost both real captures 0.5 dB: docs/decisions/0041); a repair prior's
    repaired alpha is its views' target."""
    train = ring_cameras([0, 90, 180, 270])
    arcs = RepairArcs.from_cameras(train, keep=0.8)
    model, half = _blob(0.0), _blob(0.15)
    settings = RepairSettings(views_per_arc=1, compact_resolution=64)
    for consensus in ([half], []):
        views = RepairCache(arcs, _Identity(), settings, 0, None, 0, consensus=consensus).make(0, model)
        assert views and all(v.alpha is None for v in views)
    views = RepairCache(arcs, _WithAlpha(), settings, 0, None, 0, consensus=[half]).make(0, model)
    assert views and all(v.alpha is not None for v in views)


def test_the_mask_target_weight_follows_what_the_restorer_gives():
    """``alpha_weight`` weighs a restorer's repaired alpha; a restorer without alpha has no target."""
    arcs = RepairArcs.from_cameras(ring_cameras([0, 90, 180, 270]), keep=0.8)
    settings = RepairSettings(views_per_arc=1, compact_resolution=64, alpha_weight=0.7)
    assert RepairCache(arcs, _WithAlpha(), settings, 0, None, 0).alpha_target_weight == 0.7
    assert RepairCache(arcs, _Identity(), settings, 0, None, 0).alpha_target_weight == 0.0
