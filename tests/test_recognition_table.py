"""The recognition-table experiment end to end on a small hand-made mission (records → four stages)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CLASSES = ["Ball-Valve", "Elbow", "R-Tee"]


def test_records_to_stage_metrics(tmp_path):
    syn = {"classes": CLASSES, "confusion": [[8, 2, 0], [2, 8, 0], [0, 1, 9]]}
    (tmp_path / "syn.json").write_text(json.dumps(syn))
    ball = {"Ball-Valve": 0.6, "Elbow": 0.3, "R-Tee": 0.1}  # "recognised as a ball valve"
    elbow = {"Ball-Valve": 0.3, "Elbow": 0.6, "R-Tee": 0.1}
    rows = [
        # landmark 1, an elbow: first mistaken for a ball valve, then seen with two orthogonal pipes
        {"true_class": "Elbow", "likelihood": ball, "landmark_id": 1, "configuration": None},
        {"true_class": "Elbow", "likelihood": ball, "landmark_id": 1, "configuration": 3},
        {"true_class": "Elbow", "likelihood": elbow, "landmark_id": 1, "configuration": None},
        # landmark 2, a ball valve, recognised right twice and wrong once
        {"true_class": "Ball-Valve", "likelihood": ball, "landmark_id": 2, "configuration": 2},
        {"true_class": "Ball-Valve", "likelihood": elbow, "landmark_id": 2, "configuration": None},
        {"true_class": "Ball-Valve", "likelihood": ball, "landmark_id": 2, "configuration": None},
    ]
    (tmp_path / "obs.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    out = tmp_path / "out"
    res = subprocess.run(
        [sys.executable, str(ROOT / "experiments" / "recognition_table.py"), "--records", str(tmp_path / "obs.jsonl"),
         "--syn-confusion", str(tmp_path / "syn.json"), "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    m = json.loads((out / "recognition.json").read_text())
    assert m["SYN"]["accuracy"] == pytest.approx(25 / 30)
    # DESC: argmax of each likelihood → 2 of 3 elbows wrong, 1 of 3 ball valves wrong.
    assert m["DESC"]["accuracy"] == pytest.approx(3 / 6)
    # BAYS: the elbow's evidence (ball, ball, elbow) still says ball valve; the ball valve is right
    # after its first observation (ball), tied (ball, elbow → ball wins the tie by order), right.
    assert m["DESC"]["confusion"][1] == [2, 1, 0]
    assert m["BAYS"]["confusion"][1] == [3, 0, 0]
    # SEM: from the second observation on, two orthogonal pipes rule the ball valve out.
    assert m["SEM"]["confusion"][1] == [1, 2, 0]
    assert m["SEM"]["confusion"][0] == [3, 0, 0]
    assert m["DESC"]["f1"] <= m["SEM"]["f1"]
    assert "| SEM |" in res.stdout
