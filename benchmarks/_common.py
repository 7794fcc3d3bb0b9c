"""What the benchmark scripts share: running the real `semslam` command, printing results."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path


def run_semslam(args: list[str], env: dict[str, str] | None = None) -> str:
    """Run ``python -m semslam ARGS`` (with extra environment ``env``); its stdout, or exit
    with its error."""
    proc = subprocess.run([sys.executable, "-m", "semslam", *args], capture_output=True,
                          text=True, env={**os.environ, **(env or {})}, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"semslam {' '.join(args)} failed: {proc.stderr.strip()}")
    return proc.stdout


def report(markdown: str, result: dict, json_path: Path | None = None) -> None:
    """Print a Markdown table and the JSON behind it; also write the JSON if asked."""
    print(markdown)
    print()
    print("```json")
    print(json.dumps(result, indent=2))
    print("```")
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2) + "\n")
    sys.stdout.flush()
