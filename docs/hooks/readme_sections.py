"""mkdocs hook: splice sections of the repository's README.md into documentation pages.

The README is the one place where the Quickstart and the user stories are written; the site shows
the same text instead of a copy that drifts. A page asks for a section by its exact heading:

    <!-- readme: Identify a system in one line -->

and gets that section, from its ``## `` heading to the next heading of the same level. A heading
that the README no longer has is an error, so a renamed section fails the (strict) build instead
of leaving a hole in the site.
"""

from __future__ import annotations

import re
from pathlib import Path

from mkdocs.exceptions import PluginError

MARKER = re.compile(r"^<!-- readme: (?P<heading>.+?) -->$", re.MULTILINE)


def sections(readme: str) -> dict[str, str]:
    """Heading (without ``## ``) -> the section's text, heading line included, for every level-2
    section of a Markdown text; lines inside fenced code blocks are never headings."""
    found: dict[str, list[str]] = {}
    current = None
    fenced = False
    for line in readme.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        if not fenced and line.startswith("## "):
            current = line[3:].strip()
            found[current] = []
        elif not fenced and line.startswith("# "):
            current = None          # the title closes any section
        if current is not None:
            found[current].append(line)
    return {heading: "\n".join(lines).rstrip() + "\n" for heading, lines in found.items()}


def on_page_markdown(markdown: str, page, config, files) -> str:
    if not MARKER.search(markdown):
        return markdown
    readme = Path(config["config_file_path"]).parent / "README.md"
    available = sections(readme.read_text(encoding="utf-8"))

    def splice(match: re.Match) -> str:
        heading = match.group("heading")
        if heading not in available:
            raise PluginError(
                f"{page.file.src_path}: README.md has no section {heading!r}; "
                f"its sections are {sorted(available)}")
        return available[heading]

    return MARKER.sub(splice, markdown)
