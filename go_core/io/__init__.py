"""File IO helpers shared by the library: atomic writes, images, JSON."""
