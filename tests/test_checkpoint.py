"""The one checkpoint toolkit of the training loops (go_core.io.checkpoint): numbered files kept newest-first,
resumed only for the same format and fingerprint, safetensors without pickle, and the loss log's means."""

from __future__ import annotations

import torch

from go_core.io.checkpoint import Checkpoints, CheckpointSpec, LossLog, fingerprint_of


def test_saves_keep_the_newest_and_resume_only_a_matching_one(tmp_path):
    store = Checkpoints(CheckpointSpec(tmp_path, every=2, keep=2), "loop", 3)
    assert [s for s in range(1, 8) if store.due(s, 6)] == [2, 4]  # never after the last step
    for step in (2, 4, 6):
        store.save(step, "abc", {"x": torch.tensor([float(step)])})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["loop_0000004.pt", "loop_0000006.pt"]
    newest = store.newest("abc")
    assert newest["step"] == 6 and torch.equal(newest["x"], torch.tensor([6.0]))
    assert store.newest("other") is None
    assert Checkpoints(store.spec, "loop", 4).newest("abc") is None  # another format


def test_tensor_checkpoints_carry_json_metadata(tmp_path):
    store = Checkpoints(CheckpointSpec(tmp_path, every=1, keep=1), "t", "f1")
    store.save_tensors(1, "fp", {"w": torch.ones(2)}, {"losses": [{"step": 1}]})
    store.save_tensors(2, "fp", {"w": torch.zeros(2)}, {"losses": []})
    tensors, meta = store.newest_tensors("fp")
    assert meta["step"] == 2 and meta["losses"] == [] and torch.equal(tensors["w"], torch.zeros(2))
    assert len(list(tmp_path.iterdir())) == 1 and store.newest_tensors("nope") is None


def test_loss_log_means_over_each_period_and_the_last_step():
    log = LossLog(every=3, last=7)
    for step in range(1, 8):
        log.add(step, float(step), p=step)
    assert log.entries == [
        {"step": 3, "loss": 2.0, "p": 3},
        {"step": 6, "loss": 5.0, "p": 6},
        {"step": 7, "loss": 7.0, "p": 7},
    ]
    assert log.running == 0.0


def test_fingerprints_follow_the_content():
    assert fingerprint_of({"a": 1, "b": [2]}) == fingerprint_of({"b": [2], "a": 1})
    assert fingerprint_of({"a": 1}) != fingerprint_of({"a": 2}) and len(fingerprint_of(0)) == 16
