"""runs.json: the calibration's wall time summed over invocations, killed ones included."""

from __future__ import annotations

import json

import pytest

from tactip_lab.sampling.runlog import RunLog


def test_killed_invocation_keeps_its_samples_and_time(tmp_path):
    path = tmp_path / "runs.json"
    first = RunLog(path, frames=60, flush_s=0.0, workers=2)
    for i in range(3):
        first.tick(i)
    # killed here: no finish(); the log on disk already holds the 3 samples
    on_disk = json.loads(path.read_text())
    assert len(on_disk) == 1 and on_disk[0]["samples_computed"] == 3
    assert on_disk[0]["finished"] is False and on_disk[0]["workers"] == 2

    second = RunLog(path, frames=60, flush_s=1e9)
    second.tick()
    second.tick()
    assert json.loads(path.read_text())[-1]["samples_computed"] == 0  # not flushed yet
    second.finish()
    runs = json.loads(path.read_text())
    assert [r["samples_computed"] for r in runs] == [3, 2]
    assert [r["finished"] for r in runs] == [False, True]
    s = second.summary()
    assert s["invocations"] == 2 and s["interrupted"] == 1 and s["samples_computed"] == 5
    total = sum(r["seconds"] for r in runs)
    assert s["total_s"] == pytest.approx(total)
    assert s["frames_per_s"] == pytest.approx(5 * 60 / total)


def test_damaged_log_starts_a_new_history(tmp_path):
    path = tmp_path / "runs.json"
    path.write_text("{not json")
    log = RunLog(path, frames=8)
    log.finish()
    assert log.summary()["invocations"] == 1
    assert len(json.loads(path.read_text())) == 1


def test_flush_records_an_interrupted_invocation(tmp_path):
    path = tmp_path / "runs.json"
    log = RunLog(path, frames=60, flush_s=1e9)
    log.tick()
    log.flush()  # what calibrate does on its way out of an exception
    runs = json.loads(path.read_text())
    assert runs[-1]["samples_computed"] == 1 and runs[-1]["finished"] is False
