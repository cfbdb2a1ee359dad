"""The web assets of py_trees_js (its tree drawing, jointjs, dagre, ...), taken from the
``py-trees-js`` wheel without PyQt.

The wheel carries them only inside ``py_trees_js/resources.py``, the output of Qt's resource
compiler: three byte strings (data, names, tree structure). :func:`extract` reads those with
:mod:`ast` and decodes the format (version 2: 22-byte tree nodes; zlib-compressed files carry a
4-byte big-endian length first). ``python -m sm_bt.view.assets`` downloads the pinned wheel with
``pip download --no-deps`` (its PyQt dependencies are never installed) and writes the files
where the viewer serves them from; the project's install step runs it. Nothing of py_trees_js is
kept in the repository.
"""

from __future__ import annotations

import ast
import os
import struct
import subprocess
import sys
import zipfile
import zlib
from pathlib import Path

from sm_bt.model.errors import Error

#: The wheel the assets come from (pinned; BSD-3).
WHEEL = "py-trees-js==0.7.0"
#: Where the viewer serves them from.
ASSETS = Path(__file__).with_name("static") / "py_trees_js"


def _cache() -> Path:
    """Where the downloaded wheel is kept: outside the checkout, as pip keeps its wheels, so that
    every clone on a machine shares it (``$SM_BT_CACHE``, else ``$XDG_CACHE_HOME/sm_bt``, else
    ``~/.cache/sm_bt``); next to the assets when that cannot be written."""
    root = os.environ.get("SM_BT_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "sm_bt")
    folder = Path(root) / "py-trees-js"
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return ASSETS / "wheel"
    return folder if os.access(folder, os.W_OK) else ASSETS / "wheel"


#: Where the downloaded wheel is kept (so the assets can be checked against it).
WHEELS = _cache()
#: The files the page needs (all that the wheel holds).
NEEDED = ("py_trees-0.6.js", "py_trees-0.6.css", "joint-3.0.4.min.js", "joint-3.0.4.min.css", "dagre-0.8.4.min.js",
          "graphlib-2.1.7.min.js", "lodash-4.17.11.min.js", "jquery-3.4.1.min.js", "backbone-1.4.0.js")
_NODE = 22  # bytes per tree node in format 2
_COMPRESSED, _DIRECTORY = 0x01, 0x02


class AssetsError(Error, RuntimeError):
    """The assets could not be fetched or decoded (the message says what to do)."""


def missing(folder: Path = ASSETS) -> list[str]:
    """The needed files not in ``folder``."""
    return [name for name in NEEDED if not (folder / name).is_file()]


def extract(resources_py: str) -> dict[str, bytes]:
    """Every file of a Qt resource module's source, by path (``js/py_trees-0.6.js``)."""
    tables: dict[str, bytes] = {}
    for statement in ast.parse(resources_py).body:
        if isinstance(statement, ast.Assign) and isinstance(statement.value, ast.Constant) \
                and isinstance(statement.value.value, bytes):
            for target in statement.targets:
                if isinstance(target, ast.Name):
                    tables[target.id] = statement.value.value
    try:
        data, names, tree = tables["qt_resource_data"], tables["qt_resource_name"], tables["qt_resource_struct_v2"]
    except KeyError as error:
        raise AssetsError(f"not a Qt resource module of format 2 (no {error.args[0]})") from None
    files: dict[str, bytes] = {}
    _walk(0, "", data, names, tree, files)
    return files


def _walk(node: int, prefix: str, data: bytes, names: bytes, tree: bytes, files: dict[str, bytes]) -> None:
    offset = node * _NODE
    name_offset, flags = struct.unpack_from(">IH", tree, offset)
    name = _name(names, name_offset) if node else ""
    path = f"{prefix}/{name}" if prefix else name
    if flags & _DIRECTORY:
        count, first = struct.unpack_from(">II", tree, offset + 6)
        for child in range(first, first + count):
            _walk(child, path, data, names, tree, files)
        return
    (data_offset,) = struct.unpack_from(">I", tree, offset + 10)
    (size,) = struct.unpack_from(">I", data, data_offset)
    content = data[data_offset + 4:data_offset + 4 + size]
    if flags & _COMPRESSED:
        content = zlib.decompress(content[4:])  # after the uncompressed length
    files[path] = content


def _name(names: bytes, offset: int) -> str:
    (length,) = struct.unpack_from(">H", names, offset)
    return names[offset + 6:offset + 6 + 2 * length].decode("utf-16-be")  # after the length and a hash


def from_wheel(wheel: Path) -> dict[str, bytes]:
    """The needed files of the py-trees-js ``wheel``, by file name."""
    try:
        with zipfile.ZipFile(wheel) as archive:
            source = archive.read("py_trees_js/resources.py").decode("utf-8")
    except (OSError, KeyError, zipfile.BadZipFile) as error:
        raise AssetsError(f"{wheel}: not a py-trees-js wheel with py_trees_js/resources.py ({error})") from None
    found = {Path(path).name: content for path, content in extract(source).items()}
    lacking = [name for name in NEEDED if name not in found]
    if lacking:
        raise AssetsError(f"{wheel}: lacks {', '.join(lacking)}")
    return {name: found[name] for name in NEEDED}


def ensure(folder: Path = ASSETS, wheel: Path | None = None) -> bool:
    """Write the assets into ``folder`` unless they are there; download the pinned wheel (no
    dependencies) when no ``wheel`` is given. True when something was written."""
    if not missing(folder) and kept_wheel() is not None:
        return False
    if wheel is None:
        wheel = kept_wheel() or _download()
    files = from_wheel(wheel)
    folder.mkdir(parents=True, exist_ok=True)
    for name, content in files.items():
        (folder / name).write_bytes(content)
    return True


def kept_wheel() -> Path | None:
    """The pinned py-trees-js wheel the assets were extracted from, if it was kept."""
    wheels = sorted(WHEELS.glob(f"py_trees_js-{WHEEL.split('==')[1]}-*.whl"))
    return wheels[-1] if wheels else None


def _download() -> Path:
    WHEELS.mkdir(parents=True, exist_ok=True)
    done = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--quiet",
                           "--disable-pip-version-check", WHEEL, "-d", str(WHEELS)], capture_output=True, text=True)
    wheel = kept_wheel()
    if done.returncode != 0 or wheel is None:
        raise AssetsError(f"pip download {WHEEL} failed: {done.stderr.strip()[-300:]} (the package index must be "
                          "reachable once)")
    return wheel


def main() -> int:
    try:
        wrote = ensure()
    except AssetsError as error:
        print(f"py_trees_js assets: error: {error}", file=sys.stderr)
        return 1
    print(f"py_trees_js assets: {'extracted into' if wrote else 'up to date in'} {ASSETS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["ASSETS", "NEEDED", "WHEEL", "AssetsError", "ensure", "extract", "from_wheel", "kept_wheel", "missing"]
