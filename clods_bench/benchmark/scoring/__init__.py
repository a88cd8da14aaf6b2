"""Scores of rollouts and images (rollout RMSE, PSNR/SSIM/LPIPS, stability monitors, cross-topology scoring): numbers
from arrays, no knowledge of plugins or runs."""
