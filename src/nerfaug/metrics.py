"""The test metrics, named once: which exist, how they are labelled, which direction is better, and
how many decimals a table shows. The evaluation, the statistics, the report and the study read
them from here; and the per-pixel images of a view, labelled with their units once for every
figure that draws them (a capture's uncertainty images, the report's test view)."""

from __future__ import annotations

METRICS = ("psnr", "ssim", "lpips")
METRIC_LABELS = {"psnr": "PSNR", "ssim": "SSIM", "lpips": "LPIPS"}
HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "lpips": False}
# Decimals per metric: dB to 0.01 is below any trial-to-trial spread; SSIM/LPIPS IQRs are ~1e-3.
METRIC_DECIMALS = {"psnr": 2, "ssim": 4, "lpips": 4}

# Colour-bar labels. FisherRF's per-pixel score is sum_k H_pixel[k] / (H_train[k] + lambda), a ratio
# of Fisher diagonals (`nerfaug.uncertainty.images`): it has no unit.
PIXEL_LABELS = {
    "error": "squared error, mean over RGB\n(colours in [0, 1])",
    "depth": "depth (world units)",
    "entropy": "ray entropy (bits)",
    "fisher": "FisherRF information gain\n(no unit: pixel / training Fisher)",
}

__all__ = ["HIGHER_IS_BETTER", "METRICS", "METRIC_DECIMALS", "METRIC_LABELS", "PIXEL_LABELS"]
