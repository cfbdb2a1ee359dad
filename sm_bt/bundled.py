"""The model files shipped with sm_bt (the ``models/`` folder, installed as ``sm_bt.models``)."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

# Named, not imported: the folder is mapped into the package at install time only.
_PACKAGE = "sm_bt.models"


def path(name: str) -> Path:
    """The path of a bundled model by name (``"pilot"`` or ``"pilot.yaml"``); ``KeyError`` if unknown."""
    filename = name if name.endswith(".yaml") else f"{name}.yaml"
    candidate = Path(str(resources.files(_PACKAGE).joinpath(filename)))
    if not candidate.is_file():
        raise KeyError(f"no bundled model {name!r} (bundled: {', '.join(names())})")
    return candidate


def names() -> tuple[str, ...]:
    """Names of the bundled models, sorted."""
    folder = resources.files(_PACKAGE)
    return tuple(sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml")))


def resolve(name: str | os.PathLike[str]) -> Path:
    """The file a model argument names: an existing path, else the bundled model of that name
    (``"pilot"``: a bare name only), else the path as given (for the caller to report missing)."""
    candidate = Path(name)
    if candidate.exists() or not isinstance(name, str) or os.sep in name or "/" in name:
        return candidate
    try:
        return path(name)
    except KeyError:
        return candidate
