"""Image file I/O: OpenEXR for linear HDR, PNG for display."""

from .images import linear_to_srgb8, read_exr, read_exr_channels, read_png, write_exr, write_exr_channels, write_png

__all__ = ["read_exr", "write_exr", "read_exr_channels", "write_exr_channels", "read_png", "write_png", "linear_to_srgb8"]
