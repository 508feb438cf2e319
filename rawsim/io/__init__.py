"""File input/output at the edges of rawsim: images (OpenImageIO), DNG (tifffile)."""
