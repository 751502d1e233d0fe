"""The test metrics, named once: which exist, how they are labelled, which direction is better, and
how many decimals a table shows. The evaluation, the statistics, the report and the study read
them from here."""

from __future__ import annotations

METRICS = ("psnr", "ssim", "lpips")
METRIC_LABELS = {"psnr": "PSNR", "ssim": "SSIM", "lpips": "LPIPS"}
HIGHER_IS_BETTER = {"psnr": True, "ssim": True, "lpips": False}
# Decimals per metric: dB to 0.01 is below any trial-to-trial spread; SSIM/LPIPS IQRs are ~1e-3.
METRIC_DECIMALS = {"psnr": 2, "ssim": 4, "lpips": 4}

__all__ = ["HIGHER_IS_BETTER", "METRICS", "METRIC_DECIMALS", "METRIC_LABELS"]
