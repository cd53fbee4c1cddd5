"""The sonar front-end (Guerneve et al.): multibeam elevation maps, swath registration, CAD structure
recognition and registration, pipelines and a semantic world model (see :class:`SonarFrontend`)."""

from frontends.sonar.config import SonarConfig
from frontends.sonar.frontend import SonarFrontend

__all__ = ["SonarConfig", "SonarFrontend"]
