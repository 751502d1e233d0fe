import pytest
import torch

from nerfaug.uncertainty.combined import combined_uncertainty

H = torch.tensor([1.0, 2.0, 3.0, 2.5])
D = torch.tensor([0.0, 20.0, 10.0, 5.0])


def test_minmax_default_puts_both_terms_on_the_same_scale():
    u = combined_uncertainty(H, D)
    assert torch.allclose(u, torch.tensor([0.0, 0.5, 1.0, 0.75]) + torch.tensor([0.0, 1.0, 0.5, 0.25]))


def test_none_is_the_papers_raw_sum_with_weights():
    assert torch.allclose(combined_uncertainty(H, D, normalisation="none"), H + D)
    assert torch.allclose(combined_uncertainty(H, D, 2.0, 0.5, normalisation="none"), 2 * H + 0.5 * D)


def test_authors_normalisation_divides_by_the_max_of_the_sum():
    u = combined_uncertainty(H, D, normalisation="authors")
    assert u.max().item() == pytest.approx(1.0)
    assert torch.allclose(u, combined_uncertainty(H, D) / combined_uncertainty(H, D).max())


def test_single_term_variants_are_weights():
    assert torch.allclose(combined_uncertainty(H, None, 1.0, 0.0), torch.tensor([0.0, 0.5, 1.0, 0.75]))
    assert torch.allclose(combined_uncertainty(None, D, 0.0, 1.0, "none"), D)


def test_a_constant_term_carries_no_information():
    u = combined_uncertainty(torch.full((4,), 3.0), D)
    assert torch.allclose(u, D / D.max())


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="minmax"):
        combined_uncertainty(H, D, normalisation="zscore")
    with pytest.raises(ValueError, match=">= 0"):
        combined_uncertainty(H, D, -1.0)
    with pytest.raises(ValueError, match="not given"):
        combined_uncertainty(H, None)
    with pytest.raises(ValueError, match="both weights are zero"):
        combined_uncertainty(H, D, 0.0, 0.0)
