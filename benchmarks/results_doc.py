"""What the sim-to-real benchmarks write besides their figures: the machine, the document."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path


def machine() -> dict:
    """The machine a document was computed on: platform, CPUs and the 1-minute load average at
    the end."""
    return {
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "load_1min": os.getloadavg()[0],
    }


def write(path: Path, doc: dict) -> None:
    """Write ``doc`` with its ``machine`` to ``path`` (JSON, indent 1) and say so."""
    path.write_text(json.dumps(doc | {"machine": machine()}, indent=1) + "\n")
    print(f"wrote {path}")
