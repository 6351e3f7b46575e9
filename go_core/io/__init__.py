"""File IO shared by the library: atomic writes (``atomic``), byte-reproducible ``npz`` and
``safetensors_file`` files, images (``images``), training ``curves``, mid-step checkpoints read without
running code (``checkpoint``) and where fetched weights live (``weights_cache``)."""
