"""DiffAugment (neural.augment): off is the identity, gradients pass, each policy does what
it says, draws follow the generator."""
import pytest

torch = pytest.importorskip("torch")

from neural.augment import DEFAULT_POLICY, diff_augment, parse_policy  # noqa: E402


def _images(B=4, R=16):
    return torch.rand(B, 3, R, R, generator=torch.Generator().manual_seed(1)) * 2 - 1


def test_off_is_identity():
    x = _images()
    assert diff_augment(x, "") is x and diff_augment(x, ()) is x
    assert parse_policy(" color , cutout ") == ("color", "cutout") and parse_policy("") == ()
    with pytest.raises(ValueError, match="zoom"):
        parse_policy("color,zoom")


@pytest.mark.parametrize("policy", ["color", "translation", "cutout", DEFAULT_POLICY])
def test_gradients_pass_and_images_change(policy):
    x = _images().requires_grad_(True)
    y = diff_augment(x, policy, torch.Generator().manual_seed(0))
    assert y.shape == x.shape and not torch.equal(y.detach(), x.detach())
    (y * torch.randn_like(y)).sum().backward()
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    # the same seed gives the same transform; another seed another one
    again = diff_augment(x.detach(), policy, torch.Generator().manual_seed(0))
    other = diff_augment(x.detach(), policy, torch.Generator().manual_seed(5))
    assert torch.equal(again, y.detach()) and not torch.equal(other, y.detach())


def test_translation_is_a_zero_padded_integer_shift():
    x = _images(B=6, R=16)
    y = diff_augment(x, "translation", torch.Generator().manual_seed(3))
    for xi, yi in zip(x, y):
        found = False
        for dy in range(-2, 3):           # 1/8 of 16 px
            for dx in range(-2, 3):
                ref = torch.zeros_like(xi)
                src = xi[:, max(dy, 0):16 + min(dy, 0), max(dx, 0):16 + min(dx, 0)]
                ref[:, max(-dy, 0):16 + min(-dy, 0), max(-dx, 0):16 + min(-dx, 0)] = src
                found |= torch.equal(ref, yi)
        assert found


def test_cutout_zeroes_at_most_a_half_side_square():
    x = _images(B=8, R=16) * 0.5 + 0.6      # no zero pixels of its own
    y = diff_augment(x, "cutout", torch.Generator().manual_seed(2))
    zero = (y == 0).all(1).float()            # (B, R, R), the same for every channel
    assert torch.equal((y == 0).any(1).float(), zero)
    per_image = zero.sum((1, 2))
    assert (per_image > 0).all() and (per_image <= 64).all() and (per_image == 64).any()
    kept = zero == 0
    assert torch.equal(y.permute(0, 2, 3, 1)[kept], x.permute(0, 2, 3, 1)[kept])
