"""Run the benchmarks whose JSON the Results page renders, and record each run.

    python docs/results/regenerate.py [NAME ...]      # default: every result

Each benchmark writes its JSON here (``docs/results/NAME.json``); ``runs.json`` records the
command, the date, the commit, the machine and the threads it ran with, which the page prints
under each table (``docs/hooks/results_tables.py``). Run it on a quiet machine: the timings are
what a user would see with the default threads of an ordinary install.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
CLI = [sys.executable, "-m", "aeid_struct.cli"]

#: result name -> the command's arguments (``{json}``: where it writes its JSON; ``{tmp}``: a
#: scratch folder), and the file it writes
RESULTS = {
    "leg": (["leg", "--pretrained", "--out", "{tmp}"], "{tmp}/pretrained/leg_study.json"),
    "bench-generic": (["bench-generic", "--count", "10", "--lengths", "400", "1000",
                       "--json", "{json}", "--quiet"], "{json}"),
    "bench-generic-wide": (["bench-generic", "--plants", "stable", "integrating", "unstable",
                            "--orders", "1", "2", "3", "4", "6", "8", "--count", "5",
                            "--lengths", "64", "200", "--json", "{json}", "--quiet"], "{json}"),
    "bench-channels": (["bench-generic", "--channels", "--json", "{json}", "--quiet"],
                       "{json}"),
    "bench-online": (["bench-online", "--json", "{json}", "--quiet"], "{json}"),
    "onepass": (["bench", "--onepass-only", "--json", "{json}", "--quiet"], "{json}"),
    "bench-mechanism": (["bench-mechanism", "--json", "{json}", "--quiet"], "{json}"),
}


def _shown(args: list[str]) -> str:
    """The command as a user types it: without the scratch paths and ``--quiet``."""
    out, skip = [], False
    for a in args:
        if skip:
            skip = False
            continue
        if a in ("--json", "--out"):
            skip = True
            continue
        if a != "--quiet":
            out.append(a)
    return "aeid-struct " + " ".join(out)


def _machine() -> str:
    cpu = platform.processor() or platform.machine()
    return f"{os.cpu_count()} cores ({cpu}), {platform.system()} {platform.release()}"


def _threads() -> str:
    names = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "OPENBLAS_CORETYPE")
    set_ = [f"{k}={os.environ[k]}" for k in names if k in os.environ]
    return "threads: " + (", ".join(set_) if set_ else "the defaults (no thread variable set)")


def main(names: list[str]) -> None:
    runs_path = HERE / "runs.json"
    runs = json.loads(runs_path.read_text()) if runs_path.is_file() else {}
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, text=True,
                            capture_output=True, check=True).stdout.strip()
    for name in names or list(RESULTS):
        args, written = RESULTS[name]
        with tempfile.TemporaryDirectory() as tmp:
            target = HERE / f"{name}.json"
            fill = {"tmp": tmp, "json": str(Path(tmp) / "out.json")}
            argv = [a.format(**fill) for a in args]
            started = datetime.now(timezone.utc).isoformat(timespec="seconds")
            print(f"{name}: aeid-struct {' '.join(args)}", flush=True)
            subprocess.run(CLI + argv, cwd=ROOT, check=True)
            shutil.copyfile(written.format(**fill), target)
        runs[name] = {"command": _shown(args), "date": started, "commit": commit,
                      "machine": _machine(), "threads": _threads()}
        runs_path.write_text(json.dumps(runs, indent=2) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])
