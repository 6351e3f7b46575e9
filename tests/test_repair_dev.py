"""benchmarks/repair_dev.py: its summary, its variants, and ``merge``: per-object repair_dev.py JSONs merged
into one results file."""

from __future__ import annotations

import json

import pytest
from _benchmark_module import benchmark_module

dev = benchmark_module("repair_dev")


def _run_file(path, scene: str, full: tuple, no_prior: tuple, chosen: str, second: str):
    """A repair_dev.py output of one object with two variants (psnr, ssim, lpips_star each)."""
    variants = {
        name: dict(zip(("psnr", "ssim", "lpips_star"), values, strict=True)) | {"model": "repair"}
        for name, values in (("full", full), ("no_prior", no_prior))
    }
    lora = {"restorer_chosen": chosen, "consensus_restorer": second, "tuned_psnr": 30.0, "prior_psnr": 31.0}
    record = {"variants": variants, "lora": lora, "loo_pair_psnr": 32.123456}
    path.write_text(json.dumps({"command": f"repair_dev {scene}", "threads": 1, "scenes": {scene: record}}))
    return path


def test_means_and_per_object_figures(tmp_path):
    a = _run_file(tmp_path / "a.json", "hope__box", (20.0, 0.9, 10.0), (19.0, 0.8, 11.0), "prior", "")
    b = _run_file(tmp_path / "b.json", "pyb__ball", (24.0, 0.7, 14.0), (24.5, 0.6, 13.0), "realesr", "prior")
    merged = dev.merge([a, b], None)
    summary = merged["summary"]
    assert summary["objects_compared"] == 2
    assert summary["means"]["full"] == {"psnr": 22.0, "ssim": 0.8, "lpips_star": 12.0}
    assert summary["means"]["no_prior"] == {"psnr": 21.75, "ssim": 0.7, "lpips_star": 12.0}
    box = summary["per_object"]["hope/box"]
    assert (box["restorer_chosen"], box["second_model_restorer"]) == ("prior", "own")
    assert summary["per_object"]["pyb/ball"]["second_model_restorer"] == "prior"
    assert box["fold_psnr"] == {"tuned_psnr": 30.0, "prior_psnr": 31.0}
    assert box["loo_pair_psnr"] == 32.1235
    assert merged["commands"] == ["repair_dev hope__box", "repair_dev pyb__ball"]


def test_previous_figures_set_beside(tmp_path):
    a = _run_file(tmp_path / "a.json", "hope__box", (20.0, 0.9, 10.0), (19.0, 0.8, 11.0), "prior", "")
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"summary": {"per_object": {"hope/box": {"full": {"psnr": 18.0}, "x": {}}}}}))
    previous = dev.merge([a], old)["summary"]["previous"]
    assert previous["per_object"] == {"hope/box": {"full": {"psnr": 18.0}}}


def test_an_object_twice_is_an_error(tmp_path):
    a = _run_file(tmp_path / "a.json", "hope__box", (20.0, 0.9, 10.0), (19.0, 0.8, 11.0), "prior", "")
    b = _run_file(tmp_path / "b.json", "hope__box", (21.0, 0.9, 10.0), (19.0, 0.8, 11.0), "prior", "")
    with pytest.raises(SystemExit, match="hope/box is already in another file"):
        dev.merge([a, b], None)


def test_repair_dev_sets_every_variant_against_the_comparators():
    """repair_dev.py's summary: the defaults against the coarse model, and each variant against no_prior
    (issue 34's comparator): per-scene differences, their mean, and whether LPIPS* is lower everywhere."""

    def scene(full, no_prior, coarse):
        variants = {
            name: {"psnr": p, "lpips_star": lp}
            for name, (p, lp) in (("full", full), ("no_prior", no_prior), ("no_repair", coarse))
        }
        return {
            "variants": variants,
            "psnr_change": full[0] - coarse[0],
            "lpips_star_gain": coarse[1] - full[1],
        }

    result = {"scenes": {"a": scene((24.0, 15.0), (23.0, 16.0), (22.0, 17.0)),
                         "b": scene((22.0, 16.5), (22.5, 16.0), (21.0, 17.5))}}  # fmt: skip
    dev._summarise(result)
    full = result["against_no_prior"]["full"]
    assert full["scenes"]["a"] == {"psnr_change": 1.0, "lpips_star_change": -1.0}
    assert full["scenes"]["b"] == {"psnr_change": -0.5, "lpips_star_change": 0.5}
    assert full["mean_psnr_change"] == 0.25
    assert full["lpips_lower_on_every_scene"] is False
    assert result["against_no_prior"]["no_repair"]["mean_psnr_change"] == -1.25
    assert result["against_realesr"] == {}  # no scene ran realesr
    assert result["summary"]["mean_psnr_change"] == 1.5
    assert result["summary"]["lpips_lower_on_every_scene"] is True


def test_compressed_repair_schedule_scales_every_count_alike():
    """repair_dev.py's repair_x050 / repair_x075: each iteration count of the repair's default schedule
    times the fraction (so as many refreshes and densifications), and settings the step accepts."""
    from dataclasses import replace

    from go_core.repair.settings import RepairSettings

    half = dev.VARIANTS["repair_x050"]
    assert half == {
        "repair.iterations": 2000,
        "repair.repair_iterations": 1400,
        "repair.densify_from": 200,
        "repair.densify_until": 1800,
        "repair.densify_every": 50,
        "repair.refresh_every": 100,
    }
    defaults = RepairSettings()
    short = replace(defaults, **{key.split(".")[1]: value for key, value in half.items()})
    assert short.check() == []
    refreshes = [-(-s.repair_iterations // s.refresh_every) for s in (defaults, short)]
    assert refreshes[0] == refreshes[1] == 14
    assert dev.VARIANTS["repair_x075"]["repair.iterations"] == 3000


def test_merge_subcommand_writes_the_merged_file(tmp_path, capsys):
    """``repair_dev.py merge --out OUT --note N IN...``: the note kept, each variant's means printed."""
    a = _run_file(tmp_path / "a.json", "hope__box", (20.0, 0.9, 10.0), (19.0, 0.8, 11.0), "prior", "")
    out = tmp_path / "merged.json"
    dev.main(["merge", "--out", str(out), "--note", "two files", str(a)])
    merged = json.loads(out.read_text())
    assert merged["note"] == "two files" and merged["summary"]["objects_compared"] == 1
    assert capsys.readouterr().out.splitlines()[0].split() == ["full", "20.00", "/", "0.90", "/", "10.00"]
