"""LoRA (peft) on the compact restorer's convolutions, the alternative to its full fine-tune.

``add_conv_lora`` injects rank-``r`` adapters (peft's ``inject_adapter_in_model``) into every ``Conv2d``
of the network, freezes everything else and returns the trainable parameters; the adapters' random init
draws from ``derive_seed(seed, "compact_lora")`` (never the global RNG). ``merge_conv_lora`` folds the
adapters into the convolution weights and puts the plain convolutions back, so the tuned network is saved
and run like a fully fine-tuned one.
"""

from __future__ import annotations

from torch import nn

from go_core.compact.ncnn import NcnnNet
from go_core.seeding import seeded_torch_init


def add_conv_lora(net: NcnnNet, rank: int, seed: int) -> list[nn.Parameter]:
    from peft import LoraConfig, inject_adapter_in_model

    targets = [f"convs.{k}" for k, m in net.convs.items() if type(m) is nn.Conv2d]
    if not targets:
        raise ValueError("the network has no Conv2d layer for LoRA")
    config = LoraConfig(r=int(rank), lora_alpha=int(rank), target_modules=targets, bias="none")
    with seeded_torch_init(int(seed), "compact_lora"):
        inject_adapter_in_model(config, net)
    for name, p in net.named_parameters():
        p.requires_grad_("lora_" in name)
    return [p for p in net.parameters() if p.requires_grad]


def merge_conv_lora(net: NcnnNet) -> None:
    for key, module in list(net.convs.items()):
        if hasattr(module, "merge") and hasattr(module, "get_base_layer"):
            module.merge()
            base = module.get_base_layer()
            base.weight.requires_grad_(True)
            if base.bias is not None:
                base.bias.requires_grad_(True)
            net.convs[key] = base
    for p in net.parameters():
        p.requires_grad_(True)
