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


def run_python_in(root: Path, args: list[str]) -> str:
    """``python ARGS`` with semslam imported from the source tree ``root`` (another version,
    e.g. a git worktree); its stdout, or exit with its error. Run in ``root``: ``-m`` and
    ``-c`` put the working folder first on the path, ahead of ``PYTHONPATH``, so from this
    repository the other tree would import this one."""
    env = {**os.environ, "PYTHONPATH": str(root)}
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                          cwd=root, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"python {' '.join(args[:3])} ({root}) failed: {proc.stderr.strip()}")
    return proc.stdout


def true_slot(found, truths, radius: float = 1.0):
    """The slot of ``truths`` (the exact observations of the same frame) that the detected
    slot ``found`` is: the one with the smallest mean corner distance, if under ``radius``
    (m); None otherwise."""
    import numpy as np

    corners = np.asarray(found.vCorners, dtype=float)
    best, best_d = None, radius
    for truth in truths:
        d = float(np.linalg.norm(corners - np.asarray(truth.vCorners), axis=1).mean())
        if d < best_d:
            best, best_d = truth, d
    return best


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
