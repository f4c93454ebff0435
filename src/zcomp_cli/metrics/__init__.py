"""Image metrics for ``zcomp eval``: pixel metrics (numpy), LPIPS (own AlexNet), FLIP."""

from zcomp_cli.metrics.image_metrics import mae, psnr, rmse, si_rmse, ssim

__all__ = ["mae", "psnr", "rmse", "si_rmse", "ssim"]
