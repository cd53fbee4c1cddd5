"""Monte Carlo consistency study of the EKF (the larger version of tests/test_ekf_consistency.py).

N runs of the synthetic circling mission (truth drawn from the filter's own motion model, DVL
dropouts); the vehicle NEES is sampled every second and averaged over the runs (ANEES). A
consistent filter keeps the ANEES inside the two-sided 95 % χ²(nN)/N interval about 95 % of the time
(n = 9, or 10 with the AHRS heading bias). With ``--features`` the runs include point/line observations
(EKF-SLAM), where the well-known linearisation overconfidence of EKF-SLAM may show. With ``--bias W``
the AHRS heading carries a bias, a random walk of intensity W (rad/√s) drawn from the filter's model,
which the filter estimates as its 10th state; the heading's and the bias's own NEES (1 dof) are
reported too, and ``--heading-jacobians current`` shows the textbook Jacobians instead of the
first estimates.

    python experiments/ekf_nees_study.py [--runs 50] [--duration 120] [--features] [--bias 0.002] [--png PATH]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from semslam.config import SemslamConfig
from semslam.ekf import EkfEstimator
from semslam.ekf import geometry as geo

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: tests.support

from tests.support.ekf_mission import simulate_circling  # noqa: E402

ACCEL, RATE = 0.01, 0.002


def run(
    seed: int,
    duration: float,
    features: bool,
    jacobians: str = "first_estimate",
    bias: float = 0.0,
    heading_jacobians: str = "first_estimate",
):
    """(times, vehicle NEES, heading NEES, bias NEES or None) of one run."""
    sim = simulate_circling(
        seed=seed,
        duration_s=duration,
        accel_sigma=ACCEL,
        rate_sigma=RATE,
        dropouts=((30.0, 15.0), (80.0, 15.0)),
        with_features=features,
        velocity_tau_s=None if not features else 30.0,
        track_gain=0.0 if not features else 0.1,
        heading_bias_walk=bias,
    )
    est = EkfEstimator(
        sim.metadata,
        SemslamConfig(
            motion={"accel_sigma_m_s2": ACCEL, "angular_rate_sigma_rad_s": RATE},
            ekf={"line_jacobians": jacobians, "heading_jacobians": heading_jacobians},
        ),
    )
    ts = sim.truth_stamps
    out_t, out_nees, out_yaw, out_b = [], [], [], []
    for m, obs in sim.stream():
        est.process_measurement(m)
        if obs:
            est.process_observations(m.stamp, obs)
        if m.sensor == "ahrs" and m.stamp % 1_000_000_000 == 0 and m.stamp > 0:
            i = np.searchsorted(ts, m.stamp)
            e = est.nav.state.xv.copy()
            e[:9] -= sim.truth_states[i]
            if est.nav.nv > 9:
                e[9] -= sim.extras["heading_bias"][i]
            e[3:6] = geo.wrap(e[3:6])
            P = est.nav.state.Pvv
            out_t.append(m.stamp * 1e-9)
            out_nees.append(float(e @ np.linalg.solve(P, e)))
            out_yaw.append(e[5] ** 2 / P[5, 5])
            out_b.append(e[9] ** 2 / P[9, 9] if est.nav.nv > 9 else np.nan)
    return np.array(out_t), np.array(out_nees), np.array(out_yaw), np.array(out_b)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--features", action="store_true")
    ap.add_argument(
        "--jacobians",
        default="first_estimate",
        choices=("first_estimate", "current"),
        help="ekf.line_jacobians: pipe Jacobians at the first estimate (FEJ) or the current one",
    )
    ap.add_argument("--bias", type=float, default=0.0, help="AHRS heading-bias walk (rad/√s); 0: none")
    ap.add_argument(
        "--heading-jacobians",
        default="first_estimate",
        choices=("first_estimate", "current"),
        help="ekf.heading_jacobians (with --bias)",
    )
    ap.add_argument("--png", default="experiments/out/ekf_nees.png")
    args = ap.parse_args()
    results = [
        run(s, args.duration, args.features, args.jacobians, args.bias, args.heading_jacobians)
        for s in range(args.runs)
    ]
    t = results[0][0]
    dim = 10 if args.bias > 0 else 9
    anees = np.mean([r[1] for r in results], axis=0)
    lo, hi = chi2.ppf([0.025, 0.975], dim * args.runs) / args.runs
    inside = np.mean((anees > lo) & (anees < hi))
    print(
        f"runs {args.runs}, duration {args.duration:.0f} s, features {args.features}, pipe Jacobians {args.jacobians}"
        + (f", heading bias walk {args.bias} rad/√s, heading Jacobians {args.heading_jacobians}" if args.bias else "")
    )
    print(
        f"ANEES mean {anees.mean():.2f} (dimension {dim}), 95 % bounds [{lo:.2f}, {hi:.2f}], "
        f"inside {inside:.0%} of the time"
    )
    lo1, hi1 = chi2.ppf([0.025, 0.975], args.runs) / args.runs
    for name, k in (("heading", 2), ("bias", 3)):
        a1 = np.mean([r[k] for r in results], axis=0)
        if np.isfinite(a1).all():
            inside1 = np.mean((a1 > lo1) & (a1 < hi1))
            print(
                f"{name} NEES mean {a1.mean():.2f} (1 dof), last quarter {a1[-len(a1) // 4 :].mean():.2f}, "
                f"95 % bounds [{lo1:.2f}, {hi1:.2f}], inside {inside1:.0%} of the time"
            )
    if args.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        Path(args.png).parent.mkdir(parents=True, exist_ok=True)
        fig, ax = plt.subplots(figsize=(7, 3.5))
        ax.plot(t, anees, label=f"ANEES over {args.runs} runs")
        ax.axhline(lo, color="k", ls="--", lw=0.8, label="95 % bounds")
        ax.axhline(hi, color="k", ls="--", lw=0.8)
        for s, d in ((30.0, 15.0), (80.0, 15.0)):
            ax.axvspan(s, s + d, color="0.9", label="DVL dropout" if s == 30.0 else None)
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"vehicle NEES ({dim} dof)")
        ax.legend(loc="upper right")
        fig.tight_layout()
        fig.savefig(args.png, dpi=120)
        print(f"figure: {args.png}")


if __name__ == "__main__":
    main()
