"""MkDocs hooks for `make docs`: the site's home page is README.md, the repository's front page.

Its links into docs/ (``docs/cli.md``, ``docs/view.png``) are made relative to the site, where
those pages and files sit at the top; its other relative links name files of the repository,
which the site does not have, and are refused.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files

LINK = re.compile(r"(\]\(|<img src=\")(?!https?://|#)([^)\"\s]+)")


def on_files(files: Files, config: MkDocsConfig, **kwargs: Any) -> Files:
    readme = Path(config.config_file_path).parent / "README.md"
    files.append(File.generated(config, "index.md", content=home_page(readme.read_text(encoding="utf-8"))))
    return files


def home_page(text: str) -> str:
    def relative(match: re.Match[str]) -> str:
        target = match.group(2)
        if not target.startswith("docs/"):
            raise PluginError(f"README.md links to {target}, which is not in docs/: the site has no such page")
        return match.group(1) + target.removeprefix("docs/")

    return LINK.sub(relative, text)
