"""W&B offline logging without network; the report CLI over run folders."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from grt.loggers import WandbLogger
from grt.report.plots import plot_curve


def test_wandb_offline_writes_locally_and_never_the_key(tmp_path, monkeypatch):
    secret = "sk-test-SECRET-0123456789"
    monkeypatch.setenv("WANDB_API_KEY", secret)
    monkeypatch.delenv("WANDB_MODE", raising=False)
    img = plot_curve(0.9, [[0.8, 0.5], [0.4]], tmp_path / "curve.png")
    lg = WandbLogger(project="grt-test", mode="offline")
    lg.start(tmp_path, name="t", config={"budget": {"trials": 2}})
    lg.log_iteration(1, {"best_score": 0.5})
    lg.log_images({"curve": img})
    lg.log_summary({"final_drop": 0.55})
    lg.finish()
    runs = list((tmp_path / "wandb").glob("offline-run-*"))
    assert runs, "no offline run folder written"
    for f in tmp_path.rglob("*"):
        if f.is_file():
            assert secret.encode() not in f.read_bytes(), f


def test_wandb_offline_logs_the_reports_crashshapes_table_and_videos(toy_run, tmp_path, monkeypatch):
    import shutil

    import numpy as np

    from grt.rerun import write_video

    monkeypatch.delenv("WANDB_MODE", raising=False)
    run = tmp_path / "run"
    shutil.copytree(toy_run, run)
    summary = json.loads((run / "summary.json").read_text())
    write_video([np.full((64, 64, 3), 9 * i, np.uint8) for i in range(20)], run / "videos" / "nominal_seed7.mp4")
    videos = {"pairs": [{"title": "rank 1", "seed": 7, "clips": [
        {"file": "nominal_seed7.mp4", "label": "nominal", "mode": "success"}]}]}
    lg = WandbLogger(project="grt-test", mode="offline")
    lg.start(tmp_path / "wb", name="t", config={})
    lg.log_report(run, summary, videos)
    lg.finish()
    media = [p.relative_to(tmp_path).as_posix() for p in (tmp_path / "wb").rglob("media/**/*") if p.is_file()]
    for kind, ext in (("videos", ".mp4"), ("object3D", ".stl"), ("table", ".json")):
        assert any(f"/media/{kind}/" in p and p.endswith(ext) for p in media), (kind, ext, [p[-60:] for p in media])
    table = json.loads(next((tmp_path / "wb").rglob("media/table/*.json")).read_text())
    assert [row[0] for row in table["data"]] == [s["rank"] for s in summary["crashshapes"]]
    assert "missed" in table["data"][0][5]
    assert table["data"][0][7] == "Object3D"  # the shape as a point cloud coloured by displacement


def test_wandb_mode_is_validated():
    with pytest.raises(ValueError, match="logger.mode"):
        WandbLogger(mode="sometimes")


def _fake_run(folder: Path, obj: str, selector: str, drop: float, **extra):
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(json.dumps({**extra,
        "task": "grasp", "object": obj, "selector": selector, "optimizer": "topdm", "s0": 0.9,
        "best_score": 0.9 * (1 - drop), "final_drop": drop, "delta_complexity": 0.01, "iter_at_50": 3,
        "reached_50": drop >= 0.5, "auc": 2.0, "evaluations": 11, "wall_s": 5.0}))


def test_report_cli_tables_and_csv(tmp_path):
    _fake_run(tmp_path / "0_heuristic-topdm", "mug", "heuristic", 0.6)
    _fake_run(tmp_path / "1_heuristic-topdm", "can", "heuristic", 0.2, invalid_candidates=4, validity_checked=True)
    _fake_run(tmp_path / "3_all-topdm", "can", "all", 0.2, invalid_candidates=0, validity_checked=False)
    (tmp_path / "2_x").mkdir()
    (tmp_path / "2_x" / "error.txt").write_text("boom")
    out = subprocess.run([sys.executable, "-m", "grt.report", str(tmp_path), "--csv", str(tmp_path / "t.csv")],
                         capture_output=True, text=True, check=True).stdout
    assert "| grasp | - | heuristic + topdm | - | 2 | - | 40.0 |" in out  # old summaries name no policy (nor σ)
    assert "1 failed job" in out
    assert "| 2.000 | 4 / 10 |" in out and "| 2.000 | - |" in out  # refused candidates; "-": not counted
    assert "| 2.000 | not checked |" in out  # deformer.validity=false: 0 refused would read as "all plausible"
    assert (tmp_path / "t.csv").read_text().count("\n") == 4


def test_report_cli_errors_clearly_on_empty_folder(tmp_path):
    res = subprocess.run([sys.executable, "-m", "grt.report", str(tmp_path)], capture_output=True, text=True)
    assert res.returncode != 0 and "no summary.json" in res.stderr
