"""The repair prior (issue 34): identity at initialisation, safetensors round trip and clear errors, and its
training script lowers the loss on a tiny corpus and resumes to the same weights."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from go_core.compact.prior import PriorConfig, RepairPrior, load_prior, prior_input, save_prior
from go_core.errors import MissingWeightsError
from go_core.io.npz import write_npz_deterministic
from tests._benchmark_module import benchmark_module, corpus_module


def _tiny_corpus(root: Path, objects: int = 2, views: int = 3, size: int = 32) -> Path:
    """Objects whose 'coarse' renders are the truth box-blurred and dimmed, with a dilated alpha."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:size, :size]
    for o in range(objects):
        truth, coarse, coarse_a = [], [], []
        for _ in range(views):
            cy, cx, r = rng.uniform(10, 22), rng.uniform(10, 22), rng.uniform(6, 10)
            a = ((yy - cy) ** 2 + (xx - cx) ** 2 < r**2).astype(np.float64)
            rgb = np.clip(rng.uniform(0.1, 0.9, 3) + 0.2 * np.sin(xx / 2.0)[..., None], 0, 1)
            truth.append(np.concatenate([rgb, a[..., None]], -1))
            on_white = rgb * a[..., None] + 1 - a[..., None]
            blur = sum(np.roll(on_white, s, axis=0) for s in range(-2, 3)) / 5.0  # vertical box blur
            coarse.append(np.clip(0.85 * blur + 0.1, 0, 1))
            coarse_a.append(((yy - cy) ** 2 + (xx - cx) ** 2 < (r + 2) ** 2).astype(np.float64))
        c2w = np.tile(np.eye(4), (views, 1, 1))
        arrays = {
            "novel_coarse_rgb": (np.stack(coarse) * 255).round().astype(np.uint8),
            "novel_coarse_alpha": (np.stack(coarse_a) * 255).round().astype(np.uint8),
            "novel_rgba": (np.stack(truth) * 255).round().astype(np.uint8),
            "train_rgba": (np.stack(truth[:1] * 4) * 255).round().astype(np.uint8),
            "novel_c2w": c2w,
            "train_c2w": np.tile(np.eye(4), (4, 1, 1)),
        }
        folder = root / "objects" / f"fam__obj{o}"
        folder.mkdir(parents=True)
        write_npz_deterministic(folder / "pairs.npz", arrays)
        split = "train" if o < objects - 1 else "val"
        (folder / "object.json").write_text(json.dumps({"name": f"fam/obj{o}", "split": split}))
    return root


def test_untrained_prior_is_the_identity_and_round_trips(tmp_path):
    torch.manual_seed(0)
    model = RepairPrior(PriorConfig(width=8, levels=2, reference=True))
    x = prior_input(
        torch.rand(1, 3, 32, 32), torch.rand(1, 1, 32, 32), torch.rand(1, 3, 32, 32), torch.rand(1, 1, 32, 32)
    )
    rgb, alpha = model(x)
    assert torch.equal(rgb, x[:, :3])
    torch.testing.assert_close(alpha, x[:, 3:4].clamp(1e-3, 1 - 1e-3), atol=1e-6, rtol=0)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.01 * torch.randn_like(p))
    path = save_prior(tmp_path / "p.safetensors", model, {"steps": 1})
    back = load_prior(path)
    assert back.config == model.config
    for a, b in zip(model(x), back(x), strict=True):
        assert torch.equal(a, b)


def test_missing_corrupt_or_foreign_weights_name_the_file(tmp_path):
    with pytest.raises(MissingWeightsError, match="not found") as e:
        load_prior(tmp_path / "none.safetensors")
    assert "none.safetensors" in str(e.value)
    bad = tmp_path / "bad.safetensors"
    good = save_prior(tmp_path / "good.safetensors", RepairPrior(PriorConfig(width=8, levels=2)))
    bad.write_bytes(good.read_bytes()[:-100])
    with pytest.raises(MissingWeightsError, match="corrupt") as e:
        load_prior(bad)
    assert "bad.safetensors" in str(e.value)
    from go_core.io.safetensors_file import write_safetensors

    foreign = write_safetensors(tmp_path / "f.safetensors", {"x": torch.zeros(2)}, {"format": "other"})
    with pytest.raises(MissingWeightsError, match="not a repair prior"):
        load_prior(foreign)


def _args(trainer, corpus: Path, out: Path, steps: int):
    return trainer.parse_args(
        [
            "--corpus",
            str(corpus),
            "--out",
            str(out),
            "--steps",
            str(steps),
            "--batch",
            "2",
            "--crop",
            "32",
            "--width",
            "8",
            "--levels",
            "2",
            "--lr",
            "3e-3",
            "--lpips",
            "0",
            "--no-lpips-eval",
            "--log-every",
            "5",
            "--checkpoint-every",
            "10",
            "--reference",
            "nearest",
        ]
    )


def test_training_lowers_the_loss_and_resumes_bit_identical(tmp_path):
    trainer = benchmark_module("prior/train_repair_prior")
    corpus = _tiny_corpus(tmp_path / "corpus")
    data = trainer.load_split(corpus, "train", "nearest")
    batch = trainer.draw_batch(data, np.random.default_rng(5), 4, 32)
    args = _args(trainer, corpus, tmp_path / "run", 30)

    def fixed_loss(model) -> float:
        with torch.no_grad():
            return float(trainer.loss_terms(model, None, batch, args)["total"])

    before = fixed_loss(RepairPrior(PriorConfig(width=8, levels=2, reference=True)))
    result = trainer.train(args)
    after = fixed_loss(load_prior(tmp_path / "run" / "prior.safetensors"))
    assert after < 0.8 * before, (before, after)
    val = result["validation"]["mean_over_objects"]
    assert val["psnr_out"] > val["psnr_in"]
    # a finished 20-step run keeps its last step's checkpoint; trained on to 30 steps from it (Adam and the
    # batch draws restored) it ends with the weights of the straight 30-step run
    half = tmp_path / "half"
    trainer.train(_args(trainer, corpus, half, 20))
    assert (half / "checkpoint.safetensors").exists()
    resumed = trainer.train(_args(trainer, corpus, half, 30))
    assert resumed["resumed_from"] == 20
    assert (half / "prior.safetensors").read_bytes() == (tmp_path / "run" / "prior.safetensors").read_bytes()
    # --init starts from a trained prior: no step leaves its weights as they were, and validation reports
    # the PSNR inside and outside the true silhouette
    init_args = _args(trainer, corpus, tmp_path / "init", 0)
    init_args.init = tmp_path / "run" / "prior.safetensors"
    again = trainer.train(init_args)
    trained, copied = load_prior(init_args.init), load_prior(tmp_path / "init" / "prior.safetensors")
    for key, value in trained.state_dict().items():
        assert torch.equal(value, copied.state_dict()[key]), key
    mean = again["validation"]["mean_over_objects"]
    assert mean["psnr_out"] == val["psnr_out"]
    assert mean["psnr_inside_out"] is not None and mean["psnr_outside_out"] is not None


def test_reprojection_through_a_plane_matches_the_other_camera():
    """A textured plane x = 0 seen by two cameras: warping one view into the other through the exact depth
    reproduces the other view (bilinear error only), and the same camera gives the image back."""
    from go_core.compact.reference import nearest_view, reproject

    camera_to_world = corpus_module("views").camera_to_world
    size, f = 64, 80.0
    k = np.array([f, f, size / 2, size / 2])
    cams = [camera_to_world(0.0, 0.0, 3.0), camera_to_world(11.0, 5.5, 3.07)]

    def view(c2w):
        """Image and z-depth of the plane x = 0 textured with smooth stripes, seen by ``c2w``."""
        v, u = np.mgrid[:size, :size] + 0.5
        dirs_cam = np.stack([(u - k[2]) / f, -(v - k[3]) / f, -np.ones_like(u)], -1)  # OpenGL camera frame
        dirs = dirs_cam @ c2w[:3, :3].T
        t = -c2w[0, 3] / dirs[..., 0]
        p = c2w[:3, 3] + t[..., None] * dirs
        rgb = np.stack(
            [0.5 + 0.4 * np.sin(3 * p[..., 1]), 0.5 + 0.4 * np.cos(2 * p[..., 2]), 0.3 + 0 * t], -1
        )
        return rgb, t  # t along a direction with camera z = -1: the z-depth

    (rgb0, _), (rgb1, depth1) = view(cams[0]), view(cams[1])
    ones = np.ones((size, size))
    warped, valid = reproject(depth1, ones, k, cams[1], cams[0], rgb0, ones)
    assert valid.mean() > 0.7
    err = np.abs(warped - rgb1)[valid > 0]
    assert err.max() < 0.005, err.max()  # bilinear interpolation error only (measured 6e-4)
    same, valid_same = reproject(view(cams[0])[1], ones, k, cams[0], cams[0], rgb0, ones)
    np.testing.assert_allclose(same[valid_same > 0], rgb0[valid_same > 0], atol=1e-6)
    assert nearest_view(np.stack(cams[1:]), np.stack(cams)).tolist() == [1]
    assert nearest_view(np.stack(cams[1:]), np.stack(cams), np.array([1])).tolist() == [0]  # never itself
    assert nearest_view(np.stack(cams[:1]), np.stack(cams[:1]), np.array([0])).tolist() == [0]  # the only one


def test_reference_views_warp_a_scene_photo_with_its_own_intrinsics():
    """The plane of the test above, the training photo taken with another focal length and size: the
    scene-side ``ReferenceViews`` (go_core cameras, never the target view itself) gives the novel view."""
    from go_core.camera import Camera
    from go_core.compact.reference import GL_TO_CV, ReferenceViews

    camera_to_world = corpus_module("views").camera_to_world

    def view(c2w, size, f):
        v, u = np.mgrid[:size, :size] + 0.5
        dirs = np.stack([(u - size / 2) / f, -(v - size / 2) / f, -np.ones_like(u)], -1) @ c2w[:3, :3].T
        t = -c2w[0, 3] / dirs[..., 0]
        p = c2w[:3, 3] + t[..., None] * dirs
        rgb = np.stack(
            [0.5 + 0.4 * np.sin(3 * p[..., 1]), 0.5 + 0.4 * np.cos(2 * p[..., 2]), 0.3 + 0 * t], -1
        )
        k = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
        cam = Camera("c", size, size, k, np.linalg.inv(c2w @ GL_TO_CV))
        return cam, rgb.astype(np.float32), t

    class V:
        def __init__(self, cam, image):
            self.camera, self.image, self.mask = cam, image, np.ones(image.shape[:2], np.float32)

    cam0, rgb0, _ = view(camera_to_world(0.0, 0.0, 3.0), 96, 130.0)  # the photo: larger, longer lens
    cam1, rgb1, depth1 = view(camera_to_world(11.0, 5.5, 3.07), 64, 80.0)
    refs = ReferenceViews([V(cam0, rgb0), V(cam1, rgb1)])
    assert refs.nearest(cam1) == 1 and refs.nearest(cam1, exclude=1) == 0
    warped, valid = refs.warp(cam1, depth1, np.ones_like(depth1), exclude=1)
    assert valid.mean() > 0.5
    err = np.abs(warped - rgb1)[valid > 0]
    assert err.max() < 0.01, err.max()


# --- the shipped prior ----------------------------------------------------------------------------------

REFERENCE_OUTPUTS = Path(__file__).resolve().parent / "data" / "repair_prior_outputs.npz"
MODEL_CARD = Path(__file__).resolve().parents[1] / "docs" / "repair_prior.md"


def fixed_input(channels: int, size: int = 64) -> torch.Tensor:
    """A deterministic render-like input: a shaded disc on white, its alpha, and (8 channels) a shifted copy
    as the reference view."""
    yy, xx = torch.meshgrid(torch.arange(size) + 0.5, torch.arange(size) + 0.5, indexing="ij")
    disc = (((yy - 30) ** 2 + (xx - 34) ** 2) < 20**2).float()
    shade = torch.stack([0.2 + 0.6 * xx / size, 0.7 - 0.5 * yy / size, 0.4 + 0.2 * torch.sin(xx / 3)])
    rgb = shade * disc + (1 - disc)
    x = torch.cat([rgb, disc[None]])
    if channels == 8:
        x = torch.cat([x, torch.roll(x, 3, dims=2)])
    return x[None]


def shipped_outputs() -> dict[str, np.ndarray]:
    """Each shipped prior's output on ``fixed_input``: what REFERENCE_OUTPUTS stores (``python -c "from
    tests.test_repair_prior import write_reference_outputs as w; w()"`` writes it for a new prior)."""
    from go_core.compact.prior import SHIPPED, PriorRestorer

    torch.set_num_threads(1)
    out = {}
    for name in SHIPPED:
        model = PriorRestorer.load(name)
        out[name] = model.restore(fixed_input(model.channels))[0].numpy()
    return out


def write_reference_outputs() -> None:
    REFERENCE_OUTPUTS.parent.mkdir(exist_ok=True)
    np.savez_compressed(REFERENCE_OUTPUTS, **shipped_outputs())


def test_shipped_priors_match_the_model_card_and_their_stored_outputs():
    import hashlib

    from go_core.compact.prior import SHIPPED, SHIPPED_DIR

    assert SHIPPED, "no repair prior is shipped"
    card = MODEL_CARD.read_text()
    for name, sha in SHIPPED.items():
        path = SHIPPED_DIR / f"{name}.safetensors"
        assert hashlib.sha256(path.read_bytes()).hexdigest() == sha
        assert sha in card and name in card, f"{name}: SHA-256 not in {MODEL_CARD}"
        assert path.stat().st_size <= 30 * 2**20
    outputs = shipped_outputs()
    with np.load(REFERENCE_OUTPUTS) as stored:
        assert sorted(stored.files) == sorted(outputs)
        for name, out in outputs.items():
            np.testing.assert_allclose(out, stored[name], atol=1e-5, rtol=0)


def test_inside_weighted_l1_against_hand_computed_values():
    """--inside-weight: pixels inside the true silhouette count w times in the RGB L1 (w = 1: plain L1)."""
    trainer = benchmark_module("prior/train_repair_prior")
    target = torch.zeros(1, 3, 1, 2)
    rgb = torch.tensor([0.2, 0.4]).reshape(1, 1, 1, 2).expand(1, 3, 1, 2).contiguous()
    alpha = torch.tensor([1.0, 0.0]).reshape(1, 1, 1, 2)  # left pixel inside, right outside
    assert float(trainer.rgb_l1(rgb, target, alpha, 1.0)) == float(torch.nn.functional.l1_loss(rgb, target))
    np.testing.assert_allclose(float(trainer.rgb_l1(rgb, target, alpha, 3.0)), (3 * 0.2 + 0.4) / 4, rtol=1e-6)
    np.testing.assert_allclose(
        float(trainer.rgb_l1(rgb, target, alpha, 0.5)), (0.5 * 0.2 + 0.4) / 1.5, rtol=1e-6
    )


def _rot_y(degrees: float) -> np.ndarray:
    t = np.radians(degrees)
    m = np.eye(4)
    m[[0, 0, 2, 2], [0, 2, 0, 2]] = [np.cos(t), np.sin(t), -np.sin(t), np.cos(t)]
    return m


def test_training_view_pairs_take_the_nearest_other_view_as_reference(tmp_path):
    """--train-view-share: pairs at the training views (coarse render -> photo) whose reference is the
    nearest training view by direction other than the view itself; share 0 draws what it drew before."""
    trainer = benchmark_module("prior/train_repair_prior")
    corpus = _tiny_corpus(tmp_path / "corpus")
    pairs = corpus / "objects" / "fam__obj0" / "pairs.npz"
    with np.load(pairs) as d:
        arrays = {k: d[k] for k in d.files}
    with pytest.raises(SystemExit, match="no train_coarse_depth"):
        trainer.load_split(corpus, "train", "nearest", views="train")
    size = arrays["train_rgba"].shape[1]
    photos = np.zeros((4, size, size, 4), np.uint8)
    photos[..., 3] = 255
    photos[..., 0] = np.arange(4)[:, None, None] * 60  # view i's photo: red = 60 i on an opaque frame
    arrays.update(
        train_rgba=photos,
        train_c2w=np.stack([_rot_y(a) for a in (0.0, 10.0, 90.0, 180.0)]),
        train_coarse_rgb=np.full((4, size, size, 3), 7, np.uint8),
        train_coarse_alpha=np.full((4, size, size), 255, np.uint8),
        train_coarse_depth=np.ones((4, size, size), np.float16),
    )
    write_npz_deterministic(pairs, arrays)
    views = trainer.load_split(corpus, "train", "nearest", views="train")
    assert views["names"] == ["fam/obj0"] * 4
    np.testing.assert_allclose(views["inp"], 7 / 255, rtol=1e-6)
    np.testing.assert_allclose(views["tgt"][:, 0, 0, 0], np.arange(4) * 60 / 255, rtol=1e-6)
    nearest_other = [1, 0, 1, 2]  # 0 <-> 10 degrees, 90 -> 10, 180 -> 90
    np.testing.assert_allclose(views["ref"][:, 0, 0, 0], np.array(nearest_other) * 60 / 255, rtol=1e-6)
    novel = trainer.load_split(corpus, "train", "nearest")
    plain = trainer.draw_batch(novel, np.random.default_rng(3), 4, 16)
    same = trainer.draw_batch(novel, np.random.default_rng(3), 4, 16, views, 0.0)
    for key in trainer.KEYS:
        assert torch.equal(plain[key], same[key]), key
    only_views = trainer.draw_batch(novel, np.random.default_rng(3), 8, 16, views, 1.0)
    assert torch.all(only_views["inp"] == torch.tensor(7 / 255, dtype=torch.float32))
