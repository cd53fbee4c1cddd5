"""The statistics of a study: distributions per estimator and paired ratios with bootstrap CIs.

A ratio is paired: for each mission where both estimators have the metric (finite, > 0), the
first's value over the second's (graph/ekf < 1: the graph's error is smaller). Its 95 %
confidence intervals are bootstrap intervals (:func:`scipy.stats.bootstrap`, BCa, 9999
resamples, a fixed random seed so that ``study.json`` is reproducible) of the median and of the
geometric mean of the per-mission ratios; with fewer than two pairs there is no interval.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

#: metrics whose distribution study.json gives per estimator (keys of a mission summary's estimator row)
DISTRIBUTION_METRICS = (
    "ate_rmse_m",
    "ate_rmse_se3_m",
    "rpe_rmse_m",
    "landmark_median_error_m",
    "nees_mean",
    "n_objects",
    "n_pipes",
    "n_structures",
    "objects_mapped_ratio",
    "pipes_mapped_ratio",
    "runtime_s",
    "ate_rmse_pos_yaw_m",
    "object_median_error_m",
    "pipe_median_error_m",
    "nees_share_in_pose_band",
    "object_duplicates",
    "object_missed",
    "object_false",
    "pipes_seen_mapped_ratio",
    "pipe_duplicate_ratio",
    "pipe_false",
    "structure_missed",
    "structure_false",
    "recovered_failures",
    "gps_error_rmse_m",
    "gps_error_last_m",
)
#: yes/no per mission whose share of missions study.json gives per estimator (``shares``)
SHARE_METRICS = ("objects_once", "nees_in_band")
#: error metrics whose paired ratios study.json gives
RATIO_METRICS = (
    "ate_rmse_m",
    "ate_rmse_se3_m",
    "ate_rmse_pos_yaw_m",
    "rpe_rmse_m",
    "landmark_median_error_m",
    "object_median_error_m",
    "pipe_median_error_m",
    "gps_error_rmse_m",
    "gps_error_last_m",
)
#: the pairs (numerator, denominator)
RATIO_PAIRS = (("graph", "ekf"), ("ekf", "dr"), ("graph", "dr"))
CONFIDENCE = 0.95
N_RESAMPLES = 9999


def _finite(values: Sequence) -> np.ndarray:
    a = np.array([np.nan if v is None else float(v) for v in values], float)
    return a[np.isfinite(a)]


def distribution(values: Sequence) -> dict:
    """``values`` (one per mission, None where missing) summarised: n, mean, std, min, p25, median,
    p75, max over the finite ones, and ``values`` itself."""
    a = _finite(values)
    out = {"n": int(a.size), "mean": None, "std": None, "min": None, "p25": None, "median": None, "p75": None}
    out["max"] = None
    if a.size:
        q = np.percentile(a, [0, 25, 50, 75, 100])
        out.update(
            mean=float(a.mean()),
            std=float(a.std(ddof=1)) if a.size > 1 else 0.0,
            min=float(q[0]),
            p25=float(q[1]),
            median=float(q[2]),
            p75=float(q[3]),
            max=float(q[4]),
        )
    out["values"] = [None if v is None or not np.isfinite(float(v)) else float(v) for v in values]
    return out


def _gmean(x, axis=-1):
    return np.exp(np.mean(np.log(x), axis=axis))


def bootstrap_ci(x: np.ndarray, statistic) -> list[float] | None:
    """The 95 % bootstrap (BCa) interval of ``statistic`` over ``x``; percentile intervals where BCa
    is undefined (e.g. all values equal), None with fewer than two values."""
    from scipy.stats import bootstrap

    if x.size < 2:
        return None
    if np.all(x == x[0]):
        return [float(x[0]), float(x[0])]
    for method in ("BCa", "percentile"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = bootstrap(
                (x,),
                statistic,
                confidence_level=CONFIDENCE,
                n_resamples=N_RESAMPLES,
                method=method,
                vectorized=True,
                rng=np.random.default_rng(0),
            )
        lo, hi = res.confidence_interval
        if np.isfinite(lo) and np.isfinite(hi):
            return [float(lo), float(hi)]
    return None


def paired_ratio(num: Sequence, den: Sequence) -> dict:
    """Per-mission ratios num/den (None where either is missing or not > 0) and their median and
    geometric mean with bootstrap 95 % intervals, and the share of missions below 1."""
    ratios = [
        float(a) / float(b)
        if a is not None and b is not None and np.isfinite([a, b]).all() and a > 0 and b > 0
        else None
        for a, b in zip(num, den)
    ]
    r = _finite(ratios)
    out = {"n": int(r.size), "median": None, "median_ci95": None, "geomean": None, "geomean_ci95": None}
    out["share_below_1"] = None
    if r.size:
        out.update(
            median=float(np.median(r)),
            median_ci95=bootstrap_ci(r, lambda x, axis=-1: np.median(x, axis=axis)),
            geomean=float(_gmean(r)),
            geomean_ci95=bootstrap_ci(r, _gmean),
            share_below_1=float(np.mean(r < 1)),
        )
    out["values"] = ratios
    return out


def share(values: Sequence) -> dict:
    """How many missions have a yes/no value (``n``) and the share of them where it is yes."""
    known = [bool(v) for v in values if v is not None]
    return {"n": len(known), "share": float(np.mean(known)) if known else None}


def study_statistics(summaries: Sequence[dict | None]) -> dict:
    """``distributions`` (estimator → metric → :func:`distribution`), ``shares`` (estimator → yes/no
    metric → :func:`share`), ``recognition`` (stage → F1 distribution) and ``ratios`` ("graph/ekf" →
    metric → :func:`paired_ratio`) over the missions' summaries (None for a mission without one: it
    counts as missing everywhere)."""
    estimators = list(dict.fromkeys(e for s in summaries if s for e in s["estimators"]))
    stages = list(dict.fromkeys(st for s in summaries if s for st in s["recognition_f1"]))

    def column(est: str, key: str) -> list:
        return [((s or {}).get("estimators", {}).get(est) or {}).get(key) for s in summaries]

    dists = {e: {k: distribution(column(e, k)) for k in DISTRIBUTION_METRICS} for e in estimators}
    rec = {st: {"f1": distribution([(s or {}).get("recognition_f1", {}).get(st) for s in summaries])} for st in stages}
    ratios = {
        f"{a}/{b}": {k: paired_ratio(column(a, k), column(b, k)) for k in RATIO_METRICS}
        for a, b in RATIO_PAIRS
        if a in estimators and b in estimators
    }
    shares = {e: {k: share(column(e, k)) for k in SHARE_METRICS} for e in estimators}
    return {"distributions": dists, "shares": shares, "recognition": rec, "ratios": ratios}
