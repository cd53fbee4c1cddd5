"""Recognition metrics and the paper's four recognition stages (Vallicrosa et al. 2021, Tables 3–4).

- ``SYN``  — the recogniser on held-out synthetic views (its confusion matrix is also P(Z | X));
- ``DESC`` — each real observation on its own: the class with the highest likelihood;
- ``BAYS`` — the landmark's fused posterior (Bayes over its observations so far);
- ``SEM``  — the same with the pipe-connectivity constraints.

DESC, BAYS and SEM are counted per observation, in time order: observation t of a landmark is
scored with what the map would have said right after fusing it (``mode="online"``, the paper's
sequential filter). ``mode="final"`` scores every observation with the landmark's final posterior
instead (what the finished map says). An observation without a landmark id is its own landmark.

Metrics follow the usual definitions on the confusion matrix (rows = true class, columns =
recognised): accuracy = trace / total; per class precision = TP / column sum, recall = TP / row
sum, F1 their harmonic mean (0 where undefined); the averages are macro averages over the classes
that occur in the ground truth.
"""

from __future__ import annotations

from collections.abc import Hashable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from semslam.semantics.connectivity import ConnectivityTable
from semslam.semantics.fusion import ClassFusion

STAGES = ("SYN", "DESC", "BAYS", "SEM")


@dataclass(frozen=True)
class ObservationRecord:
    """One recognised object observation, for scoring. ``true_class`` comes from ground truth;
    ``likelihood`` is P(Z | X) as the recogniser gave it; ``landmark_id`` the back-end's global id
    (None if it was never associated); ``configuration`` the pipe configuration seen (1–4)."""

    true_class: str
    likelihood: Mapping[str, float]
    landmark_id: Hashable | None = None
    configuration: int | None = None


def confusion_matrix(true: Sequence[str], predicted: Sequence[str], classes: Sequence[str]) -> np.ndarray:
    """Counts ``C[i, j]`` of true class ``classes[i]`` recognised as ``classes[j]``."""
    idx = {c: i for i, c in enumerate(classes)}
    unknown = (set(true) | set(predicted)) - set(idx)
    if unknown:
        raise KeyError(f"labels not among the classes: {sorted(unknown)}")
    c = np.zeros((len(classes), len(classes)), dtype=np.int64)
    if len(true):
        np.add.at(c, ([idx[t] for t in true], [idx[p] for p in predicted]), 1)
    return c


def classification_metrics(confusion: np.ndarray | Sequence[Sequence[int]], classes: Sequence[str]) -> dict:
    """Accuracy, macro precision / recall / F1 and the per-class figures of a confusion matrix.

    Keys: ``accuracy``, ``precision``, ``recall``, ``f1`` (macro over classes with support),
    ``per_class`` {class: {precision, recall, f1, support}}, ``confusion``, ``classes``, ``n``.
    ``None`` where there is nothing to measure (an empty matrix).
    """
    c = np.asarray(confusion, dtype=np.float64)
    n = c.sum()
    tp = np.diag(c)
    col, row = c.sum(axis=0), c.sum(axis=1)
    precision = np.divide(tp, col, out=np.zeros_like(tp), where=col > 0)
    recall = np.divide(tp, row, out=np.zeros_like(tp), where=row > 0)
    pr = precision + recall
    f1 = np.divide(2 * precision * recall, pr, out=np.zeros_like(tp), where=pr > 0)
    present = row > 0
    per_class = {
        k: {"precision": float(precision[i]), "recall": float(recall[i]), "f1": float(f1[i]), "support": int(row[i])}
        for i, k in enumerate(classes)
    }

    def avg(v):
        return float(v[present].mean()) if present.any() else None

    return {
        "accuracy": float(tp.sum() / n) if n > 0 else None,
        "precision": avg(precision),
        "recall": avg(recall),
        "f1": avg(f1),
        "per_class": per_class,
        "confusion": c.astype(np.int64).tolist(),
        "classes": list(classes),
        "n": int(n),
    }


def _argmax(d: Mapping[str, float], classes: Sequence[str]) -> str:
    values = [d.get(c, 0.0) for c in classes]  # np.argmax's first maximum, without an array per record
    return classes[values.index(max(values))]


def stage_predictions(
    records: Iterable[ObservationRecord],
    classes: Sequence[str],
    *,
    connectivity: ConnectivityTable | None = None,
    prior: Mapping[str, float] | None = None,
    mode: str = "online",
) -> dict[str, list[str]]:
    """The recognised class of every record at the DESC, BAYS and SEM stages (record order)."""
    if mode not in ("online", "final"):
        raise ValueError(f"mode must be 'online' or 'final', got {mode!r}")
    fusion = ClassFusion(classes, prior=prior, connectivity=connectivity)
    out: dict[str, list[str]] = {"DESC": [], "BAYS": [], "SEM": []}
    keys = []
    for i, r in enumerate(records):  # one pass: records may stream (a long survey's, never all kept)
        key = r.landmark_id if r.landmark_id is not None else ("__unassociated__", i)
        if mode == "final":
            keys.append(key)
        fusion.update(key, r.likelihood, r.configuration)
        out["DESC"].append(_argmax(r.likelihood, classes))
        if mode == "online":
            out["BAYS"].append(fusion.map_class(key, use_connectivity=False))
            out["SEM"].append(fusion.map_class(key, use_connectivity=True))
    if mode == "final":
        out["BAYS"] = [fusion.map_class(k, use_connectivity=False) for k in keys]
        out["SEM"] = [fusion.map_class(k, use_connectivity=True) for k in keys]
    return out


def recognition_metrics(
    records: Iterable[ObservationRecord],
    classes: Sequence[str],
    *,
    syn_confusion: np.ndarray | None = None,
    connectivity: ConnectivityTable | None = None,
    prior: Mapping[str, float] | None = None,
    mode: str = "online",
) -> dict[str, dict | None]:
    """Metrics of the four stages, in the ``metrics.json`` "recognition" layout
    (``{stage: {accuracy, precision, recall, f1, confusion, ...}}``); SYN is None without its
    confusion matrix, and a stage without observations has ``None`` figures. ``records`` are read
    once, in order (an iterator is enough: none is kept)."""
    truth: list[str] = []

    def noted(rows):  # the true classes noted as the records pass: one pass over a stream
        for r in rows:
            truth.append(r.true_class)
            yield r

    preds = stage_predictions(noted(records), classes, connectivity=connectivity, prior=prior, mode=mode)
    out: dict[str, dict | None] = {
        "SYN": classification_metrics(syn_confusion, classes) if syn_confusion is not None else None
    }
    for stage in ("DESC", "BAYS", "SEM"):
        out[stage] = classification_metrics(confusion_matrix(truth, preds[stage], classes), classes)
    return out


def format_table(metrics: Mapping[str, dict | None], digits: int = 3) -> str:
    """The stages as a Markdown table (accuracy and macro precision / recall / F1), then each
    stage's confusion matrix."""

    def f(x):
        return "–" if x is None else f"{x:.{digits}f}"

    lines = ["| stage | n | accuracy | precision | recall | F1 |", "|---|---|---|---|---|---|"]
    for stage in STAGES:
        m = metrics.get(stage)
        if m is None:
            continue
        lines.append(
            f"| {stage} | {m['n']} | {f(m['accuracy'])} | {f(m['precision'])} | {f(m['recall'])} | {f(m['f1'])} |"
        )
    for stage in STAGES:
        m = metrics.get(stage)
        if m is None:
            continue
        cls = m["classes"]
        lines += ["", f"{stage} confusion (rows true, columns recognised)", "",
                  "| true \\ recognised | " + " | ".join(cls) + " |", "|---" * (len(cls) + 1) + "|"]  # fmt: skip
        for k, row in zip(cls, m["confusion"]):
            lines.append(f"| {k} | " + " | ".join(str(v) for v in row) + " |")
    return "\n".join(lines)
