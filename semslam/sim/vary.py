"""Randomised worlds: what a simulator seed draws besides the noise realisations.

Before this module, a seed already drew, with every other parameter fixed at its default:
the tank's pipe tree on the fixed 3×3×3 lattice (routing, fitting classes and positions), the
field's seabed relief, structure positions / yaws and pipeline routes, every sensor's noise
*realisation*, the placement and lengths of the DVL dropout bursts (at a fixed rate) and the
sign of the heading bias drift. :func:`draws` adds the *parameters* of the world, per aspect:

============  =====================================================================================
aspect        tank (``scenario="tank"``)                    field (``scenario="field"``)
============  =====================================================================================
layout        lattice nodes 3–4 × 3–4 × 2–3, spaced         seabed relief ±0.4–1.2 m from 3–9 bumps;
              0.50–0.65 m (3 nodes) or 0.45–0.50 m (4)      pipelines 6–8 m to 10–15 m long, leaving
              horizontally, 0.40–0.60 m vertically; 12 to   their hubs within 10–35°
              min(0.8 × nodes, 26) lattice edges (pipes
              before mid-edge splits); objects ≥ 60–85 % of
              the edges (all six classes); centre ±0.2 m
trajectory    ellipse semi-axes 3.0–3.6 m (N) × 2.3–2.7 m   line spacing 4.5–6.0 m, altitude 4–6 m,
              (E); mean depth 2.5–3.2 m, swing 0.10–0.35    speed 0.4–0.7 m/s; wobble 0.25–1.0°
              m; 130–190 s per loop (0.09–0.14 m/s);
              roll/pitch wobble 0.5–2.0°
noise         DVL σ 5–20 mm/s; AHRS roll/pitch σ 0.05–0.2°, heading σ 0.25–1.0°, heading bias drift
              0.5–4° over the mission, rate σ 1–4 mrad/s; depth σ 1–5 cm; laser range σ 2–10 mm
              (tank) / multibeam range σ 1–3 cm (field)
dropouts      DVL random dropouts 0–15 % of the mission,    0–5 %, bursts 0.5–1.5 s to +1–4 s
              bursts 1–3 s to +2–10 s longer
start         start bearing around the structure 0–360°     survey pattern shifted ±half a line
                                                            spacing north, ±4 m east
============  =====================================================================================

The tank's ranges keep the structure ≥ 1.3 m inside the vehicle's ellipse, and every layout they
allow is generated (checked over seeds 1–1000).
The noise ranges are those of the sensors' data sheets (a 600 kHz-class DVL's single-ping
velocity noise, a fibre-optic / MEMS AHRS, a 0.01–0.05 %-of-full-scale pressure sensor, a
structured-light laser scanner, a 400 kHz multibeam). Seed 0 draws nothing, whatever the aspects:
it stays the default mission (the demo's). Each aspect draws from a random stream of its own, so
varying one never changes what another draws. The draws are *defaults* under the user's
simulation YAML and options: what the user sets explicitly is never redrawn.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable
from functools import partial

import numpy as np

from semslam.errors import ConfigError
from semslam.sim.streams import rng_stream

ASPECTS = ("layout", "trajectory", "noise", "dropouts", "start")


def parse_aspects(text: str | Iterable[str] | None) -> tuple[str, ...]:
    """``"all"``, ``"none"`` / ``""`` or a comma-separated subset of :data:`ASPECTS` → the aspects, in
    :data:`ASPECTS` order. Unknown names are a :class:`ConfigError` naming them."""
    if text is None:
        return ()
    items = [s.strip() for s in (text.split(",") if isinstance(text, str) else text)]
    items = [s for s in items if s]
    if items == ["all"]:
        return ASPECTS
    if items in ([], ["none"]):
        return ()
    unknown = [s for s in items if s not in ASPECTS]
    if unknown:
        raise ConfigError(f"--vary: unknown aspect {unknown[0]!r} (choose from all, none, {', '.join(ASPECTS)})")
    return tuple(a for a in ASPECTS if a in items)


def _u(rng: np.random.Generator, lo: float, hi: float, digits: int = 4) -> float:
    return round(float(rng.uniform(lo, hi)), digits)


def _tank_layout(rng) -> dict:
    grid = [int(rng.integers(3, 5)), int(rng.integers(3, 5)), int(rng.integers(2, 4))]
    spacing = [_u(rng, 0.50, 0.65) if n == 3 else _u(rng, 0.45, 0.50) for n in grid[:2]] + [_u(rng, 0.40, 0.60)]
    n_edges = int(rng.integers(12, min(round(0.8 * np.prod(grid)), 26) + 1))
    return {
        "structure": {
            "grid": grid,
            "spacing_m": spacing,
            "n_edges": n_edges,
            "min_objects": int(round(n_edges * rng.uniform(0.6, 0.85))),
            "min_pipes": min(12, n_edges),
            "center_xy_m": [_u(rng, -0.2, 0.2), _u(rng, -0.2, 0.2)],
        }
    }


def _tank_trajectory(rng) -> dict:
    return {
        "trajectory": {
            "semi_axes_m": [_u(rng, 3.0, 3.6), _u(rng, 2.3, 2.7)],
            "work_depth_m": _u(rng, 2.5, 3.2),
            "depth_swing_m": _u(rng, 0.10, 0.35),
            "loop_period_s": _u(rng, 130.0, 190.0, 2),
            "roll_pitch_amplitude_deg": _u(rng, 0.5, 2.0),
        }
    }


def _field_layout(rng) -> dict:
    lo = _u(rng, 6.0, 8.0, 2)
    return {
        "seabed": {"relief_m": _u(rng, 0.4, 1.2), "bumps": int(rng.integers(3, 10))},
        "layout": {"pipe_length_m": [lo, round(lo + _u(rng, 4.0, 7.0, 2), 2)], "max_hub_angle_deg": _u(rng, 10, 35, 2)},
    }


def _field_trajectory(rng) -> dict:
    return {
        "trajectory": {
            "line_spacing_m": _u(rng, 4.5, 6.0),
            "altitude_m": _u(rng, 4.0, 6.0),
            "speed_m_s": _u(rng, 0.4, 0.7),
            "roll_pitch_amplitude_deg": _u(rng, 0.25, 1.0),
        }
    }


def _noise(rng, scenario: str) -> dict:
    out = {
        "dvl": {"sigma_m_s": _u(rng, 0.005, 0.02, 5)},
        "ahrs": {
            "roll_pitch_sigma_deg": _u(rng, 0.05, 0.2),
            "heading_sigma_deg": _u(rng, 0.25, 1.0),
            "heading_bias_drift_deg": _u(rng, 0.5, 4.0),
            "angular_rate_sigma_rad_s": _u(rng, 0.001, 0.004, 5),
        },
        "depth": {"sigma_m": _u(rng, 0.01, 0.05)},
    }
    if scenario == "tank":
        out["laser"] = {"range_sigma_m": _u(rng, 0.002, 0.01, 5)}
    else:
        out["sonar"] = {"range_sigma_m": _u(rng, 0.01, 0.03, 5)}
    return out


def _dropouts(rng, scenario: str) -> dict:
    if scenario == "tank":
        rate, b0 = _u(rng, 0.0, 0.15), _u(rng, 1.0, 3.0, 2)
        b1 = round(b0 + _u(rng, 2.0, 10.0, 2), 2)
    else:
        rate, b0 = _u(rng, 0.0, 0.05), _u(rng, 0.5, 1.5, 2)
        b1 = round(b0 + _u(rng, 1.0, 4.0, 2), 2)
    return {"dvl": {"random_dropout_rate": rate, "burst_s": [b0, b1]}}


def _start(rng, scenario: str) -> dict:
    if scenario == "tank":
        return {"trajectory": {"start_angle_deg": _u(rng, 0.0, 360.0, 2)}}
    return {"trajectory": {"center_m": [_u(rng, -2.75, 2.75), _u(rng, -4.0, 4.0)]}}


_DRAWS = {
    "tank": {
        "layout": _tank_layout,
        "trajectory": _tank_trajectory,
        "noise": partial(_noise, scenario="tank"),
        "dropouts": partial(_dropouts, scenario="tank"),
        "start": partial(_start, scenario="tank"),
    },
    "field": {
        "layout": _field_layout,
        "trajectory": _field_trajectory,
        "noise": partial(_noise, scenario="field"),
        "dropouts": partial(_dropouts, scenario="field"),
        "start": partial(_start, scenario="field"),
    },
}


def draws(scenario: str, seed: int, aspects: Collection[str]) -> dict:
    """The parameters ``seed`` draws for the ``aspects`` of ``scenario`` ("tank" or "field"), as a
    nested mapping of simulator configuration keys (empty for seed 0)."""
    if scenario not in _DRAWS:
        raise ConfigError(f"--vary: the {scenario!r} scenario has no randomised parameters")
    out: dict = {}
    if seed == 0:
        return out
    for aspect in parse_aspects(list(aspects)):
        merge_into(out, _DRAWS[scenario][aspect](rng_stream(seed, f"vary_{aspect}")))
    return out


def merge_into(base: dict, top: dict) -> dict:
    """Deep-merge ``top`` into ``base`` (in place; ``top`` wins on leaves) and return ``base``."""
    for k, v in top.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            merge_into(base[k], v)
        else:
            base[k] = v
    return base
