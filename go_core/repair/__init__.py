"""Gaussian repair: distance-aware repair views, λ(π) and w(t), 3D-noise statistics, pairs, tuning."""
