"""User-facing errors: the CLI prints them as one line and exits non-zero, without a traceback."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

M = TypeVar("M", bound=BaseModel)


class SemslamError(Exception):
    """An error caused by the user's input (file, topic, message, configuration), not by a bug."""


class MissionError(SemslamError):
    """A mission (bag) cannot be read: missing, not a bag, truncated, malformed message."""


class ConfigError(SemslamError):
    """A configuration file or value is invalid."""


def one_line(exc: BaseException) -> str:
    """What a library's exception says, on one line (a user error quotes it after naming the file)."""
    text = " ".join(str(exc).split())
    name = type(exc).__name__
    if name.endswith("ReaderError"):  # rosbags' own messages say what is wrong; the class adds nothing
        return text or name
    return f"{name}: {text}" if text else name


def solver_failure(exc: BaseException) -> str:
    """What a solver's exception says in a diagnostic: its first non-empty line (GTSAM's
    indeterminate-system message starts with a blank one and explains itself over a paragraph),
    with the variable it names."""
    text = str(exc)
    line = next((ln.strip() for ln in text.splitlines() if ln.strip()), type(exc).__name__)
    near = re.search(r"\(Symbol: (\w+)\)", text)
    return f"{line} {near.group(1)}" if near else line


def validated(model: type[M], data: M | Mapping[str, Any] | None, where: str) -> M:
    """``data`` validated as ``model`` (an instance of it is taken as it is); an invalid key is a
    ConfigError naming it under ``where`` (e.g. ``frontends.laser.pipes.min_length: ...``)."""
    if isinstance(data, model):
        return data
    try:
        return model.model_validate(dict(data or {}))
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(x) for x in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        raise ConfigError(f"{where}.{key}: {msg}" if key else f"{where}: {msg}") from None
