"""MkDocs hooks for tumblebot's documentation site.

* ``<!-- cli-reference -->`` in a page becomes the reference of every command, generated from
  the parsers ``tumblebot --help`` itself prints (so the page and ``--help`` cannot drift).
* A link that leaves ``docs/`` (a report, a benchmark, a source file) is checked against the
  repository: a missing file fails the strict build. Images are site files under ``_repo/``
  (:func:`on_files`); other files become their repository path in code type, since the site has no
  copy of the source tree.
"""

from __future__ import annotations

import argparse
import logging
import os
import posixpath
import re
from pathlib import Path
from typing import Any

log = logging.getLogger("mkdocs.plugins.tumblebot")

CLI_MARKER = "<!-- cli-reference -->"
IMAGE_SUFFIXES = {".png", ".gif", ".svg", ".jpg", ".jpeg"}
LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(\s*)(```|~~~)")
HELP_COLUMNS = "100"

IMAGE_FOLDERS = ("reports", "policies", "benchmarks")


def _subcommands(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return list(action.choices.items())
    return []


def _reference_of(parser: argparse.ArgumentParser, name: str, depth: int) -> list[str]:
    out = [f"{'#' * depth} `{name}`", ""]
    if parser.description:
        out += [parser.description, ""]
    out += ["```text", parser.format_help().rstrip(), "```", ""]
    for child_name, child in _subcommands(parser):
        out += _reference_of(child, f"{name} {child_name}", min(depth + 1, 4))
    return out


def cli_reference() -> str:
    """Every command's ``--help``, as Markdown (the page ``reference/cli.md`` shows)."""
    from tumblebot.cli import build_parser

    saved = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = HELP_COLUMNS  # argparse wraps to the terminal; the page is fixed
    try:
        root = build_parser()
        lines = ["## `tumblebot`", "", "```text", root.format_help().rstrip(), "```", ""]
        for name, child in _subcommands(root):
            lines += _reference_of(child, f"tumblebot {name}", 2)
    finally:
        if saved is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = saved
    return "\n".join(lines)


def _outside_link(match: re.Match[str], page_dir: str, docs_dir: Path, repo: Path, src: str) -> str:
    bang, text, target = match.groups()
    if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
        return match.group(0)  # a URL, an anchor on this page, or a site-absolute path
    path = target.partition("#")[0]
    resolved = posixpath.normpath(posixpath.join(page_dir, path))
    if not resolved.startswith("../"):
        return match.group(0)  # inside docs/: MkDocs checks it
    repo_path = posixpath.normpath(posixpath.join("docs", resolved))
    if not (repo / repo_path).exists():
        log.warning("%s links to %s, which the repository does not contain", src, repo_path)
        return match.group(0)
    if Path(repo_path).suffix.lower() in IMAGE_SUFFIXES:
        depth = page_dir.count("/") + 1 if page_dir else 0
        return f"{bang}[{text}]({'../' * depth}_repo/{repo_path})"  # a site file (on_files)
    shown = f"`{repo_path}`"
    if text.strip("`") in (repo_path, posixpath.dirname(repo_path), repo_path.rstrip("/")):
        return shown
    return f"{text} ({shown})"


def _rewrite_links(markdown: str, src_uri: str, docs_dir: Path) -> str:
    repo = docs_dir.parent
    page_dir = posixpath.dirname(src_uri)
    out: list[str] = []
    fence: str | None = None
    for line in markdown.split("\n"):
        opened = FENCE.match(line)
        if opened:
            marker = opened.group(2)
            fence = marker if fence is None else (None if marker == fence else fence)
            out.append(line)
            continue
        if fence is None:
            line = LINK.sub(lambda m: _outside_link(m, page_dir, docs_dir, repo, src_uri), line)
        out.append(line)
    return "\n".join(out)


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    if CLI_MARKER in markdown:
        markdown = markdown.replace(CLI_MARKER, cli_reference())
    return _rewrite_links(markdown, page.file.src_uri, Path(config["docs_dir"]))


def on_files(files: Any, config: Any) -> Any:
    """The repository's committed pictures (reports, policy curves) as site files under ``_repo/``."""
    from mkdocs.structure.files import File

    repo = Path(config["docs_dir"]).parent
    for folder in IMAGE_FOLDERS:
        for image in sorted((repo / folder).rglob("*")):
            if image.suffix.lower() in IMAGE_SUFFIXES and image.is_file():
                rel = image.relative_to(repo).as_posix()
                files.append(File.generated(config, f"_repo/{rel}", abs_src_path=str(image)))
    return files
