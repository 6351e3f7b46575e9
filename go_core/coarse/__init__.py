"""Coarse 3DGS: the visual ``hull`` that seeds the Gaussians, and the training ``loop`` that fits them to the
training views (``settings``: every knob, ``losses``: L1 + D-SSIM + mask BCE + depth, ``optim``: Adam per
parameter group, ``densify``: the densification strategies, ``floaters``: floater elimination,
``regularizers``: the optional shape and opacity terms, ``depth_prior``: monocular disparity priors for the
depth loss). The repair stage (``go_core.repair``) continues training with the same loop.
"""
