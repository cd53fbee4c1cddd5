"""The front-end registry finds a front-end declared by a throw-away distribution's entry point."""

import sys
import textwrap

import pytest

from semslam.errors import ConfigError
from semslam.mission import MissionMetadata, PointCloud
from semslam.registry import Frontend, available_frontends, create_frontends, load_frontend_class


@pytest.fixture
def throwaway_distribution(tmp_path, monkeypatch):
    """An installed-looking distribution (package + .dist-info with entry_points.txt) on sys.path."""
    pkg = tmp_path / "thirdparty_fe"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        textwrap.dedent(
            """
            from pydantic import BaseModel

            from semslam.errors import validated
            from semslam.mission import PointCloud
            from semslam.observations import PointObservation
            from semslam.registry import Frontend

            class CentroidConfig(BaseModel):
                scale: float = 1.0

            class CentroidFrontend(Frontend):
                name = "centroid"
                consumes = (PointCloud,)
                config_model = CentroidConfig

                def __init__(self, metadata, config):
                    self.config = validated(CentroidConfig, config, "frontends.centroid")
                    self.scale = self.config.scale

                def process(self, measurement, view):
                    c = measurement.points.mean(axis=0) * self.scale
                    return [PointObservation(measurement.stamp, measurement.sensor, position=c)]

            class Broken:
                pass
            """
        )
    )
    dist = tmp_path / "thirdparty_fe-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdparty-fe\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[semslam.frontends]\ncentroid = thirdparty_fe:CentroidFrontend\nbroken = thirdparty_fe:Broken\n"
        "missing = thirdparty_fe:DoesNotExist\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("thirdparty_fe", None)


def test_third_party_frontend_is_found_and_runs(throwaway_distribution):
    assert "centroid" in available_frontends()
    (fe,) = create_frontends(["centroid"], MissionMetadata(), {"centroid": {"scale": 2.0}})
    cloud = PointCloud(5, "laser", points=[[1, 0, 0], [3, 0, 0]])
    (obs,) = fe.process(cloud, view=None)
    assert obs.position.tolist() == [4.0, 0.0, 0.0]


def test_builtin_frontends_are_registered_by_entry_point():
    assert {"oracle", "laser", "sonar"} <= set(available_frontends())


def test_every_loaded_frontend_is_a_frontend_with_its_hooks(throwaway_distribution):
    """A plug-in derives from Frontend, or declares every member; one written before the base class
    gets the base class's defaults for the hooks it lacks, so that the driver never asks for them."""
    for name in ("oracle", "laser", "sonar", "centroid"):
        cls = load_frontend_class(name)
        assert issubclass(cls, Frontend)
        assert isinstance(cls.uses_view, bool) and isinstance(tuple(cls.parallel_consumes), tuple)
        assert callable(cls.finish)
    (fe,) = create_frontends(["centroid"], MissionMetadata(), {})
    assert fe.finish(None) is None and fe.uses_view and fe.parallel_consumes == ()


def test_unknown_broken_and_unloadable_frontends_are_user_errors(throwaway_distribution):
    with pytest.raises(ConfigError, match="unknown front-end 'nope'"):
        load_frontend_class("nope")
    with pytest.raises(ConfigError, match="'broken'.*lacks name, consumes, config_model, process"):
        load_frontend_class("broken")
    with pytest.raises(ConfigError, match="'missing'.*failed to load"):
        load_frontend_class("missing")
