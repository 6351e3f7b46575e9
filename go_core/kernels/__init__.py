"""Compiled CPU kernels that are not rendering: the fused Adam step of the Gaussian optimiser
(``csrc/adam.cpp``, go_core.coarse.optim) and the photometric loss terms, SSIM / L1 / mask BCE in one pass
(``csrc/ssim.cpp``, go_core.coarse.losses). They are built into the one CPU extension with the rasterizer
(go_core/render/build.py lists every source) and share its vector header (render/csrc/simd.h).
"""
