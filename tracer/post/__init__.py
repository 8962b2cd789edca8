"""Image operations on an assembled frame: denoising."""
