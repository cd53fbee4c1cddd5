"""User-facing errors: the CLI prints them as one line and exits non-zero, without a traceback."""


class SemslamError(Exception):
    """An error caused by the user's input (file, topic, message, configuration), not by a bug."""


class MissionError(SemslamError):
    """A mission (bag) cannot be read: missing, not a bag, truncated, malformed message."""


class ConfigError(SemslamError):
    """A configuration file or value is invalid."""
