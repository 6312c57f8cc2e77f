"""mkdocs hook: render the Results page's tables from the benchmarks' own JSON.

A page asks for a benchmark's tables by name:

    <!-- results: bench-generic -->

and gets them rendered by the library's own formatter from ``docs/results/<name>.json`` (the
file the benchmark wrote with ``--json``), followed by the run that produced it (command, date,
commit, machine and threads, from ``docs/results/runs.json``). The tables therefore cannot drift
from what the code measured: to change a number, run the benchmark again. A missing file, an
unknown name or a run without its record fails the (strict) build.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from mkdocs.exceptions import PluginError

MARKER = re.compile(r"^<!-- results: (?P<name>[\w-]+) -->$", re.MULTILINE)


def _leg(data: dict) -> str:
    # the study writes its Table I (ours beside the paper's) into its JSON as Markdown
    return data["markdown"]


def _generic(data: list) -> str:
    from aeid_struct.studies.generic_bench import Row, format_tables

    # a text table (aligned columns), shown as the benchmark prints it
    return "```text\n" + format_tables([Row(**row) for row in data]).rstrip() + "\n```"


def _channels(data: dict) -> str:
    from aeid_struct.studies.channels_bench import ChannelRow, format_channels

    return "```text\n" + format_channels([ChannelRow(**row) for row in data["rows"]]).rstrip() \
        + "\n```"


def _online(data: dict) -> str:
    from aeid_struct.studies.bench_online import format_tables

    return format_tables(data)


def _onepass(data: dict) -> str:
    from aeid_struct.studies.onepass_tables import format_onepass_tables

    return format_onepass_tables(data["onepass"])


def _mechanism(data: list) -> str:
    from aeid_struct.studies.mechanism_bench import report

    return "```text\n" + report(data).strip() + "\n```"


#: result name -> the formatter of its JSON
RENDER = {"leg": _leg, "bench-generic": _generic, "bench-generic-wide": _generic,
          "bench-channels": _channels, "bench-online": _online, "onepass": _onepass,
          "bench-mechanism": _mechanism}


def _run_line(run: dict) -> str:
    return (f"*Run:* `{run['command']}` on {run['date']} at commit `{run['commit']}`; "
            f"{run['machine']}; {run['threads']}.")


def on_page_markdown(markdown: str, page, config, files) -> str:
    if not MARKER.search(markdown):
        return markdown
    folder = Path(config["config_file_path"]).parent / "docs" / "results"
    runs = json.loads((folder / "runs.json").read_text(encoding="utf-8"))

    def render(match: re.Match) -> str:
        name = match.group("name")
        path = folder / f"{name}.json"
        if name not in RENDER or not path.is_file() or name not in runs:
            raise PluginError(f"{page.file.src_path}: no results {name!r}: needs a formatter "
                              f"(one of {sorted(RENDER)}), {path} and its run in runs.json")
        data = json.loads(path.read_text(encoding="utf-8"))
        return RENDER[name](data).rstrip() + "\n\n" + _run_line(runs[name]) + "\n"

    return MARKER.sub(render, markdown)
