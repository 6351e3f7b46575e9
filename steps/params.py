"""One typed params class per step: the names, types, ranges, defaults and docs of every setting.

The runner resolves pipeline.yaml, ``--profile`` and ``--set`` against these classes at plan time (an unknown
name, a wrong type or a value out of range is one clear error before anything runs) and hands each step its
instance: ``run(ctx, inputs, params: CoarseParams)``; steps read ``params.iterations``, never a default of
their own. Each default is written here only (pipeline.yaml holds only values a user changes;
tests/test_defaults_once.py); steps/registry.py pairs each class with its step.

Adding a setting: a field here (``setting(default, ge=..., doc=...)``, ``Literal[...]`` for choices). A field
whose type is another step's params class (``coarse: CoarseParams`` in ``LooParams``) is filled by the runner
with that step's resolved params: a step that needs another step's settings receives them explicitly (and
they are part of its cache key).

Torch-free (the runner imports it for ``status``); the step modules import it only for type checking, so
a change here reruns nothing by itself (a changed value changes the keys of the steps that use it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from go_core.coarse.settings import Backend, CoarseConfig
from go_core.config import setting
from go_core.mesh.settings import MeshSettings
from go_core.repair.settings import ConsensusMember, LooSettings, RepairSettings

Precision = Literal["auto", "bf16", "fp16", "fp32"]
ExportFormat = Literal["ply", "spz", "splat", "compressed_ply"]


@dataclass
class SceneParams:
    views: int = setting(0, ge=0, doc="0: the scene's own training split; N: choose N training views")
    max_size: int = setting(
        1600, ge=0, doc="downscale (with a warning) so the longest image side is at most this (0: keep)"
    )
    poses: Literal["given", "estimate", "initial"] = setting(
        "given",
        doc="estimate: SfM on the training views, verified (COLMAP-free profile, docs/evaluation.md); "
        "initial: start from the folder's initial_poses.json (the folder's own poses stay the reference)",
    )
    pose_matcher: Literal["sift", "disk"] = setting(
        "sift", doc="features for poses: estimate, and for SfM on a folder of photos"
    )
    photo_size: int = setting(
        256,
        ge=64,
        doc="photo folder: long side of the training and test images (256: the size of the dev renders, "
        "at which every default of the chain was chosen; speed vs error in docs/photos.md)",
    )
    sfm_size: int = setting(
        800,
        ge=64,
        doc="photo folder: long side of the images SfM extracts features from (measured on a 66-photo "
        "turntable capture: 512 px 1.53 deg median rotation error, 640 px wrong poses, 800 px 0.41 deg; "
        "benchmarks/results/photos_sfm_ethiopian_head.json)",
    )
    sfm_features: int = setting(2048, ge=64, doc="photo folder: SIFT/DISK features per photo at most")
    sfm_window: int = setting(
        6, ge=1, doc="photo folder: each photo is matched with the next N (and 2N, 4N...)"
    )
    photo_masks: Literal["auto", "u2netp", "grabcut"] = setting(
        "auto", doc="photo folder: how every photo is masked (auto: u2netp when fetched, else GrabCut)"
    )
    salient_model: Literal["u2netp"] = setting(
        "u2netp", doc="photo folder: the weights-cache model of photo_masks u2netp/auto (in the cache key)"
    )
    min_registered: float = setting(
        0.9,
        gt=0,
        le=1,
        doc="photo folder: the fraction of photos SfM must pose, else one error naming the rest",
    )


@dataclass
class MaskParams:
    method: Literal["auto", "provided", "grabcut", "onnx", "u2netp"] = setting(
        "auto",
        doc="auto | provided | grabcut | onnx | u2netp (auto: provided, else onnx_model, else u2netp when "
        "fetched, else grabcut)",
    )
    salient_model: Literal["u2netp"] = setting(
        "u2netp", doc="the weights-cache model of method u2netp (and auto); its file is in the cache key"
    )
    auto_threshold: float = setting(0.5, gt=0, lt=1, doc="u2netp: saliency above this is the object")
    auto_crop_margin: float = setting(
        0.08, ge=-1, doc="u2netp: second pass on a square crop this much wider than the object (<0: off)"
    )
    auto_refine: Literal["none", "grabcut"] = setting("none", doc="u2netp: GrabCut seeded by the saliency")
    object_box: str = setting("", doc="x0,y0,x1,y1@PHOTO: a box around the object on one photo (u2netp)")
    auto_vote: float = setting(
        0.95, ge=0, le=1, doc="u2netp, >= 8 posed views: keep what this share of views masks in 3D (0: off)"
    )
    onnx_model: str = setting("", doc="local path of an ISNet/U2-Net ONNX export")
    onnx_normalization: Literal["imagenet", "isnet"] = setting(
        "imagenet",
        doc="imagenet (U2-Net) | isnet (mean 0.5, std 1)",
    )
    grabcut_iterations: int = setting(5, ge=1)
    grabcut_border: float = setting(0.03, ge=0, lt=0.5, doc="image border fraction seeded as background")
    binary_edges: Literal["smooth", "keep"] = setting(
        "keep",
        doc="provided masks with only 0 and 1: smooth = each outline pixel's estimated coverage "
        "(go_core.scene.mask_edges) | keep",
    )


@dataclass
class DepthParams:
    model_path: str = setting("", doc="local transformers DPT / Depth-Anything folder; empty: no depth loss")


@dataclass
class HullParams:
    init: Literal["hull", "random"] = setting(
        "hull",
        doc="hull | random (ablation: vanilla 3DGS random init in a camera-derived cube)",
    )
    num_points: int = setting(20000, ge=1, doc="points sampled inside the hull (rejection sampling)")
    random_points: int = setting(20000, ge=1, doc="points of the random-init ablation")
    all_but_one: bool = setting(False, doc="keep points inside all masks but one (authors' code)")
    mask_threshold: float = setting(0.5, gt=0, lt=1)
    opacity: float = setting(0.1, gt=0, lt=1, doc="initial opacity of every Gaussian")
    align_poses: bool = setting(
        False,
        doc="turn and move the training cameras until their silhouettes agree before carving (--profile cf)",
    )
    align_iterations: int = setting(80, ge=1, doc="align_poses: Adam steps per coarse-to-fine level")
    align_centre_sigma: float = setting(
        0.05, ge=0, doc="align_poses: prior on each camera centre's move, x mean camera distance (0: held)"
    )
    align_rotation_sigma: float = setting(
        0.0, ge=0, doc="align_poses: prior on each camera's turn, degrees (0: none)"
    )


@dataclass
class CoarseParams(CoarseConfig):
    """The coarse 3DGS settings (go_core.coarse.settings.CoarseConfig) and the step's checkpoint period."""

    checkpoint_every: int = setting(500, ge=0, doc="0: no mid-step checkpoints")


@dataclass
class WeightsParams:
    repair_model: Literal["auto", "sd15", "compact"] = setting(
        "auto", doc="auto: sd15 when its weights are configured, else compact"
    )
    compact_model: str = setting("realesr-animevideov3-x4", doc="pretrained restorer (`weights fetch`)")
    sd15_path: str = setting("${GO_SD15_PATH:-}", doc="SD1.5 diffusers folder or single file")
    controlnet_path: str = setting("${GO_CONTROLNET_TILE_PATH:-}", doc="ControlNet tile folder or file")
    clip_path: str = setting("${GO_CLIP_PATH:-}", doc="optional CLIP ViT-L/14 text encoder")
    single_file_config: str = setting("${GO_SD15_CONFIG:-}", doc="diffusers config folder for single files")

    def chosen_model(self) -> tuple[Literal["sd15", "compact"], str]:
        """(the repair model the weights step runs, why): compact when named, or auto without an SD1.5 or
        ControlNet path; else sd15 (auto with a path given runs sd15, or stops on incomplete weights). The
        params alone decide it, so the runner knows it at plan time (steps/weights.py runs by it)."""
        if self.repair_model == "compact":
            return "compact", "weights.repair_model compact"
        if self.repair_model == "sd15":
            return "sd15", "weights.repair_model sd15"
        if self.sd15_path or self.controlnet_path:
            return "sd15", "weights.repair_model auto, SD1.5 weights configured"
        return "compact", "weights.repair_model auto, no SD1.5 weights configured"


@dataclass
class LooParams(LooSettings):
    """The leave-one-out runs (go_core.repair.settings.LooSettings) with the coarse step's settings."""

    workers: int = setting(
        0,
        ge=0,
        doc="processes for the N independent runs (0: auto, one per thread of the step on a CPU, one on "
        "CUDA; the artifacts are bit-identical for any count)",
    )
    coarse: CoarseParams = setting(default_factory=CoarseParams, doc="filled with the coarse step's params")


@dataclass
class NoisePairsParams:
    p0: float = setting(1.0, ge=0, le=1, doc="initial probability of a fresh noise pair")
    decay: float = setting(0.995, gt=0, le=1, doc="p_manual *= decay each time a noise pair is used")
    noise_scale: float = setting(1.0, ge=0, doc="multiplies the leave-one-out statistics (1 = paper)")
    preview_size: int = setting(128, ge=0, doc="thumbnail size of preview.png (0: no preview)")
    backend: Backend = "auto"


@dataclass
class TuneParams:
    finetune: bool = setting(
        True, doc="false: no fine-tuning, the pretrained repair model (loo and noise_pairs are skipped)"
    )
    sd15_prompt: str = setting("a photo of xxy5syt00", doc="SD1.5: the prompt the LoRA is tuned with")
    sd15_rank: int = setting(
        64, ge=1, doc="SD1.5: LoRA rank on UNet + ControlNet transformer blocks and CLIP attention"
    )
    sd15_alpha: float = setting(64.0, gt=0, doc="SD1.5: LoRA alpha")
    sd15_unet: bool = setting(True, doc="SD1.5: LoRA on the UNet")
    sd15_controlnet: bool = setting(True, doc="SD1.5: LoRA on the ControlNet")
    sd15_text_encoder: bool = setting(True, doc="SD1.5: LoRA on the CLIP text encoder")
    sd15_steps: int = setting(1800, ge=0, doc="SD1.5: LoRA tuning steps")
    sd15_lr: float = setting(0.001, gt=0, doc="SD1.5: AdamW learning rate")
    betas: tuple[float, float] = setting((0.9, 0.999), ge=0, lt=1, doc="Adam(W) betas (both models)")
    sd15_weight_decay: float = setting(0.01, ge=0, doc="SD1.5: AdamW weight decay")
    sd15_resolution: int = setting(512, ge=64, multiple_of=64, doc="SD1.5: square side fed to SD")
    checkpoint_every: int = setting(300, ge=0)
    use_loo_pairs: bool = setting(True, doc="false: noise pairs only")
    sd15_precision: Precision = setting("auto", doc="SD1.5 on CUDA: auto/bf16 | fp16 | fp32; CPU: fp32")
    compact_steps: int = setting(400, ge=0, doc="compact repair model: full fine-tune steps (L1, Adam)")
    compact_lr: float = setting(0.0001, gt=0, doc="compact: Adam learning rate")
    compact_method: Literal["full", "lora"] = setting("full", doc="compact: full fine-tune or LoRA (peft)")
    compact_rank: int = setting(8, ge=1, doc="compact: LoRA rank (compact_method lora)")
    compact_region: Literal["all", "inside"] = setting(
        "all", doc="compact: RGB loss over the whole view, or inside the clean view's mask (a repair prior)"
    )
    compact_resolution: int = setting(256, ge=1, doc="compact: pair side (a multiple of the model's scale)")
    prior_choice: str = setting(
        "go-repair-prior-4",
        doc="compact: a repair prior that repairs as shipped instead of the tuned restorer where it restores "
        "the held-out leave-one-out views better ('' never; docs/real_captures.md, docs/repair_prior.md)",
    )
    choice_steps: int = setting(
        200,
        ge=1,
        doc="compact: tuning steps of each held-out fold of prior_choice, at most compact_steps (the final "
        "tuning's steps; docs/decisions/0018-fold-steps-200.md)",
    )
    backend: Backend = "auto"


@dataclass
class RepairParams(RepairSettings):
    """Gaussian repair (go_core.repair.settings.RepairSettings), its ablations and the coarse settings."""

    mode: Literal["full", "no_repair"] = setting("full", doc="no_repair: the coarse model is the result")
    use_lora: bool = setting(True, doc="false: the pretrained repair model, not the tune step's (ablation)")
    sd15_guidance_scale: float = setting(1.0, ge=0, doc="SD1.5: classifier-free guidance (> 1: on)")
    lpips_net: Literal["vgg", "alex"] = "vgg"
    sd15_precision: Precision = setting("auto", doc="SD1.5 on CUDA: auto/bf16 | fp16 | fp32; CPU: fp32")
    consensus: bool = setting(
        True,
        doc="a second model (coarse + repair at a derived seed); each novel view's repair input is what both "
        "render (docs/repair.md)",
    )
    consensus_member: ConsensusMember = setting(
        "repaired", doc="consensus: the second model is its coarse fit repaired, or the coarse fit alone"
    )
    consensus_restorer: str = setting(
        "choice",
        doc="consensus: the restorer of the second model's repair: 'choice' the tune step's (the prior of "
        "tune.prior_choice where the blend of both restorers won the held-out folds, else the run's own), "
        "'' the run's own (tuned), or a compact model's name, not tuned (e.g. go-repair-prior-4)",
    )
    consensus_models: int = setting(
        2,
        ge=2,
        le=8,
        doc="consensus: how many models agree (the run's and consensus_models - 1 more, each a coarse fit "
        "and its repair at its own derived seed)",
    )
    coarse: CoarseParams = setting(default_factory=CoarseParams, doc="filled with the coarse step's params")


@dataclass
class ExportParams:
    sh_degree: int = setting(3, ge=0, le=3, doc="SH degree written (f_rest zero-padded; 3: viewers)")
    formats: tuple[ExportFormat, ...] = setting(
        ("ply", "spz"),
        doc="files: ply (INRIA, always), spz (Niantic), splat (antimatter15), compressed_ply (SuperSplat)",
    )

    def check(self) -> list[str]:
        return (
            [] if "ply" in self.formats else ["export.formats must hold ply (the model the other steps read)"]
        )


@dataclass
class MeshParams(MeshSettings):
    """Mesh extraction (go_core.mesh.extract.MeshSettings) and the visual hull's baseline mesh."""

    hull_resolution: int = setting(128, ge=16, le=512, doc="voxels along the hull box's longest side")


@dataclass
class TurntableParams:
    frames: int = setting(60, ge=1, doc="frames on the ellipse fitted to the TRAINING cameras")
    path_frames: int = setting(15, ge=1, doc="camera_path.mp4: frames between consecutive training cameras")
    fps: int = setting(20, ge=1)
    max_size: int = setting(256, ge=0, doc="longest image side of the frames (0: training resolution)")
    sheet_frames: int = setting(8, ge=1, doc="frames on the contact sheet")
    background: tuple[float, float, float] = setting((1.0, 1.0, 1.0), ge=0, le=1)
    backend: Backend = "auto"


@dataclass
class EvalParams:
    lpips_nets: list[Literal["vgg", "alex"]] = setting(["vgg", "alex"], doc="vgg = the paper's LPIPS")
    masked: bool = setting(False, doc="also report PSNR/SSIM/LPIPS over the GT mask only")
    backend: Backend = setting("auto", doc="renderer backend")
    grid_views: int = setting(100, ge=0, doc="test views shown in test_grid.png")
    thumb_size: int = setting(128, ge=1, doc="longest side of each grid thumbnail, px")
    test_pose_iterations: int = setting(
        200, ge=0, doc="refined-pose models: per-test-view pose fit, model frozen"
    )
    geometry_samples: int = setting(
        300_000, ge=1000, doc="points sampled on each surface for Chamfer / F-score (docs/geometry.md)"
    )
