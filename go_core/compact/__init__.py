"""The compact repair model, the default when Stable Diffusion 1.5 is not configured: genuine pretrained
Real-ESRGAN / waifu2x restorers read from their ncnn model files (``ncnn``, ``weights``) into torch
(``restorer``), tuned per scene on the self-generated pairs (``tuning``: a full fine-tune, or ``lora``), and
run by the repair loop in one pass per view (``engine``). The SD1.5 model is ``go_core.diffusion``.
"""
