"""The validation set of issue 80 (benchmarks/validation_set.py, .json) and its runner's statistics
(benchmarks/validate.py): which objects count, the dev protocol's cameras, the paired bootstrap."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest

from tests._benchmark_module import benchmark_module

ROOT = Path(__file__).resolve().parents[1]
DEV = ROOT.parent / "shared" / "data" / "dev"
vs = benchmark_module("validation_set")
validate = benchmark_module("validate")


@pytest.fixture(scope="module")
def manifest() -> dict:
    return vs.load_manifest()


@pytest.fixture(scope="module")
def corpus(manifest) -> dict:
    return json.loads((ROOT / manifest["prior_corpus"]).read_text())


def test_the_set_is_large_enough_and_spans_the_hard_cases(manifest):
    kinds = vs.kinds(manifest)
    assert sum(k == "rendered" for k in kinds.values()) >= 15
    assert len(kinds) >= 20
    tags = {t for e in manifest["rendered"] for t in e.get("tags", [])}
    for case in ("concave", "thin parts", "textureless", "shiny", "dark"):
        assert case in tags, case


def test_no_object_the_prior_trained_on_or_reserved(manifest, corpus):
    vs.check_held_out(manifest, corpus)  # raises on a trained, reserved or unknown corpus object
    trained = vs.prior_training_names(corpus)
    assert len(trained) >= 40 and not trained & {e["name"] for e in manifest["rendered"]}


@pytest.mark.parametrize(
    "name, message",
    [
        ("pybullet_objects/blob_001", "trained on"),  # in the prior's training split
        ("stable_hope_objects/bigger_milk", "reserved"),  # a reserved object's rescaled variant
        ("custom_objects/not_in_the_corpus", "not a held-out"),
    ],
)
def test_a_trained_or_reserved_object_is_refused(manifest, corpus, name, message):
    bad = copy.deepcopy(manifest)
    bad["rendered"].append({"name": name, "source": "corpus"})
    with pytest.raises(ValueError, match=message):
        vs.check_held_out(bad, corpus)


def test_manifest_errors_name_the_problem(tmp_path, manifest):
    bad = copy.deepcopy(manifest)
    bad["rendered"].append(dict(bad["rendered"][0]))
    path = tmp_path / "set.json"
    path.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="duplicate"):
        vs.load_manifest(path)


@pytest.mark.skipif(not (DEV / "milk").is_dir(), reason="needs ../shared/data/dev (the dev scenes)")
@pytest.mark.parametrize("split", ["train", "test"])
def test_views_are_the_dev_scenes_own(manifest, split):
    """The dev protocol's views, drawn here, are the ones the dev scenes were rendered from."""
    train, test = vs.dev_protocol_views(manifest["protocol"])
    frames = json.loads((DEV / "milk" / f"transforms_{split}.json").read_text())["frames"]
    ours = train if split == "train" else test
    assert len(frames) == len(ours)
    for frame, (az, el) in zip(frames, ours, strict=True):
        assert frame["azimuth_deg"] == pytest.approx(az, abs=1e-5)
        assert frame["elevation_deg"] == pytest.approx(el, abs=1e-5)


def test_parse_profile():
    p = validate.parse_profile("default")
    assert (p.label, p.profile, p.overrides) == ("default", None, {})
    assert validate.parse_profile("fast").profile == "fast"
    p = validate.parse_profile("coarse=default:repair.mode=no_repair;coarse.iterations=100")
    assert (p.label, p.profile) == ("coarse", None)
    assert p.overrides == {"repair.mode": "no_repair", "coarse.iterations": 100}
    assert validate.parse_profile("x=prior:tune.finetune=true").overrides == {"tune.finetune": True}


def test_paired_bootstrap_against_the_normal_interval():
    rng = np.random.default_rng(1)
    diffs = rng.normal(0.3, 1.0, size=400)
    row = validate.paired_bootstrap(diffs)
    half = 1.96 * diffs.std(ddof=1) / np.sqrt(diffs.size)
    assert row["mean"] == pytest.approx(diffs.mean())
    assert row["ci95"][0] == pytest.approx(diffs.mean() - half, abs=0.15 * half)
    assert row["ci95"][1] == pytest.approx(diffs.mean() + half, abs=0.15 * half)
    assert validate.paired_bootstrap(np.full(7, -0.25))["ci95"] == [-0.25, -0.25]
    with pytest.raises(ValueError, match="no paired scene"):
        validate.paired_bootstrap(np.array([]))


def _ok(psnr: float, lpips: float, cpu: float, eval_cpu: float = 0.0) -> dict:
    steps = {"coarse": {"cpu_s": cpu - eval_cpu}, "eval": {"cpu_s": eval_cpu}}
    return {"status": "ok", "psnr": psnr, "ssim": 0.9, "lpips_star": lpips, "cpu_s": cpu, "steps": steps}


def test_paired_table_by_hand():
    results = {
        "a": {"base": _ok(20.0, 10.0, 100.0, eval_cpu=50.0), "fast": _ok(19.0, 11.0, 20.0, eval_cpu=10.0)},
        "b": {"base": _ok(30.0, 5.0, 200.0), "fast": _ok(30.5, 5.0, 60.0)},
        "c": {"base": _ok(25.0, 8.0, 300.0), "fast": {"status": "failed", "error": "x"}},
    }
    table = validate.paired_table(results, ["base", "fast"])
    assert table["paired_scenes"] == ["a", "b"]  # c failed under fast: not paired
    assert table["means"]["base"]["psnr"] == 25.0 and table["means"]["fast"]["cpu_s"] == 40.0
    row = table["against_first"]["fast"]
    assert row["psnr"]["mean"] == pytest.approx(-0.25) and row["psnr"]["n"] == 2
    assert row["lpips_star"]["mean"] == pytest.approx(0.5)
    assert row["cpu_s_ratio_median"] == pytest.approx(0.25)  # median of 0.2 and 0.3
    assert row["cpu_s_ratio_range"] == [0.2, 0.3]
    # without eval (a measurement): a 10/50 = 0.2, b 60/200 = 0.3 (no eval step time recorded there)
    assert table["means"]["base"]["cpu_s_reconstruct"] == pytest.approx(125.0)
    assert row["cpu_s_reconstruct_ratio_range"] == [0.2, 0.3]


def test_kept_records_are_reused_only_under_the_same_key(tmp_path):
    """A call resumes from the records of an earlier one; another code version's record is not reused."""
    profiles = [validate.parse_profile("a=default"), validate.parse_profile("b=fast")]
    key = {"spec": profiles[0].spec(), "code": "c1", "seed": 0}
    path = validate.record_path(tmp_path, "s", "a")
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({"key": key, "result": _ok(20.0, 9.0, 50.0)}))
    out = validate.run_scene("s", "unused", str(tmp_path), profiles, 0, "c1", kept_only=True)
    assert out["a"] == _ok(20.0, 9.0, 50.0)
    assert out["b"]["status"] == "not run"  # no record for b: nothing ran
    other = validate.run_scene("s", "unused", str(tmp_path), profiles, 0, "c2", kept_only=True)
    assert other["a"]["status"] == "not run"
    assert validate.paired_table({"s": out}, ["a", "b"])["paired_scenes"] == []


def test_a_resumed_step_keeps_the_scene_out_of_the_pairs():
    """A step finished by a resumed run records only its last attempt's CPU seconds: not comparable."""
    resumed = _ok(19.0, 11.0, 20.0)
    resumed["steps"]["coarse"]["resumed_from"] = 1800
    results = {
        "a": {"base": _ok(20.0, 10.0, 100.0), "fast": resumed},
        "b": {"base": _ok(30.0, 5.0, 200.0), "fast": _ok(30.5, 5.0, 60.0)},
    }
    assert validate.resumed_steps(resumed["steps"]) == ["coarse"]
    assert validate.paired_table(results, ["base", "fast"])["paired_scenes"] == ["b"]


def test_markdown_quotes_the_table():
    results = {
        "a": {"base": _ok(20.0, 10.0, 100.0, eval_cpu=50.0), "fast": _ok(19.0, 11.0, 20.0, eval_cpu=10.0)},
        "b": {"base": _ok(30.0, 5.0, 200.0), "fast": _ok(30.5, 5.0, 60.0)},
    }
    table = validate.paired_table(results, ["base", "fast"])
    text = validate.markdown(results, ["base", "fast"], table)
    assert "| a | 20.00 / 10.00 / 100 | 19.00 / 11.00 / 20 |" in text
    assert "| mean | **25.00 / 7.50 / 150** | **24.75 / 8.00 / 40** |" in text
    assert "fast against base (2 scenes): PSNR -0.25 dB" in text and "CPU x0.25 (median" in text
