"""What a study runs: one :class:`MissionTask` per mission, as plain data (what a Dask task gets).

A task holds only paths, a seed and configurations as JSON-able mappings; the simulator's and
semslam's configurations are resolved and validated here, on the client, so that a wrong key is
one error before the study starts rather than one failure per mission.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from semslam.errors import ConfigError, SemslamError


@dataclass(frozen=True)
class MissionTask:
    """One mission of a study. ``source`` is ``{"kind": "scenario", "scenario", "seed", "vary",
    "sim_config"}`` (``sim_config`` the simulator's whole resolved configuration) or
    ``{"kind": "bag", "path"}``; ``config`` is semslam's resolved configuration."""

    mission: str
    study_dir: str
    source: dict
    config: dict
    frontends: list[str] | None = None
    hold_out_gps: str | None = None  # `semslam compare --hold-out-gps`: GPS fixes kept as the reference
    timeout_s: float | None = None
    keep_bag: bool = False
    frontend_workers: int = 1  # the mission's front-end processes (its share of the cores; not in its identity)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> MissionTask:
        return cls(**d)

    def identity(self) -> dict:
        """What determines the mission's results (not where or how long it may run)."""
        return {
            "source": self.source,
            "config": self.config,
            "frontends": self.frontends,
            "hold_out_gps": self.hold_out_gps,
        }

    def identity_hash(self) -> str:
        return hashlib.sha256(json.dumps(self.identity(), sort_keys=True).encode()).hexdigest()[:16]

    def reproduce(self) -> str:
        """The `semslam` command line that recomputes this mission alone."""
        fe = f" --frontends {','.join(self.frontends)}" if self.frontends else ""
        fe += f" --hold-out-gps {self.hold_out_gps}" if self.hold_out_gps else ""
        if self.source["kind"] == "bag":
            return f"semslam compare {self.source['path']} --config {self.mission}/config.yaml{fe} --out OUT"
        s = self.source
        return (
            f"semslam simulate {s['scenario']} --seed {s['seed']} --vary none "
            f"--sim-config {self.mission}/sim_config.yaml --out mission.bag && "
            f"semslam compare mission.bag --config {self.mission}/config.yaml{fe} --out OUT"
        )


def parse_seeds(text: str) -> list[int]:
    """``"0-49"``, ``"3"``, ``"0,4,9-12"`` → the seeds in that order, without repeats."""
    seeds: list[int] = []
    for part in (p.strip() for p in text.split(",")):
        m = re.fullmatch(r"(\d+)(?:\s*-\s*(\d+))?", part)
        if not m:
            raise ConfigError(f"--seeds: {part!r} is not a seed or a range A-B (e.g. 0-49 or 0,3,7-9)")
        a, b = int(m[1]), int(m[2] if m[2] is not None else m[1])
        if b < a:
            raise ConfigError(f"--seeds: empty range {part!r}")
        seeds += [s for s in range(a, b + 1) if s not in seeds]
    return seeds


def semslam_config(path: str | Path | None, scenario: str | None) -> dict:
    """semslam's configuration for a study, as plain data: the ``--config`` file if given; otherwise
    the tank scenario's is the demo's (its pipes' radius as the laser's prior), any other the defaults."""
    from semslam.config import SemslamConfig, load_config

    if path is not None:
        cfg = load_config(path)
    elif scenario == "tank":
        from semslam.demo import demo_config

        cfg = demo_config()
    else:
        cfg = SemslamConfig()
    return cfg.model_dump(mode="json")


def scenario_tasks(
    study_dir: Path,
    scenario: str,
    seeds: Sequence[int],
    vary: Sequence[str],
    config: dict,
    sim_config: str | Path | None = None,
    **common,
) -> list[MissionTask]:
    """One task per seed of ``scenario``; every simulator configuration resolved (and so checked) here."""
    from semslam.sim.config import read_yaml_mapping
    from semslam.sim.scenarios import resolve_config

    data = read_yaml_mapping(sim_config, "simulation configuration") if sim_config is not None else None
    source = None if sim_config is None else str(sim_config)
    tasks = []
    for seed in seeds:
        sim = resolve_config(scenario, seed, vary, data, source).model_dump(mode="json")
        src = {"kind": "scenario", "scenario": scenario, "seed": seed, "vary": list(vary), "sim_config": sim}
        tasks.append(MissionTask(f"{scenario}-seed{seed}", str(study_dir), src, config, **common))
    return tasks


def bag_tasks(study_dir: Path, bags: Sequence[Path], config: dict, **common) -> list[MissionTask]:
    """One task per bag, named after the bag (``name``, ``name-2``, ... when two share a name)."""
    names: set[str] = set()
    tasks = []
    for bag in bags:
        if not bag.exists():
            raise SemslamError(f"{bag}: no such bag")
        stem = bag.name.removesuffix(".bag").removesuffix(".mcap") or "mission"
        name, k = stem, 2
        while name in names:
            name, k = f"{stem}-{k}", k + 1
        names.add(name)
        src = {"kind": "bag", "path": str(bag.resolve())}
        tasks.append(MissionTask(name, str(study_dir), src, config, **common))
    return tasks
