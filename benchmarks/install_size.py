"""Install time and venv size of `pip install SRC` in a fresh venv (torch first, as the README says).

    python benchmarks/install_size.py SRC --label after   # -> results/install_size.json

SRC is a source tree (the package as a user clones it). The timed part is `pip install SRC` alone, with
torch already in the venv and pip's cache off (every wheel fetched as a new user's would be). Writes (or
adds its label to) the JSON: seconds, venv size in MB (total and without torch), and which of the optional
stacks (diffusers, transformers, peft, ray) the install brought.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

OPTIONAL = ("diffusers", "transformers", "peft", "ray")


def _size_mb(path: Path) -> float:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink()) / 1e6


def measure(src: Path, torch_spec: str = "torch==2.13.0") -> dict:
    """Fresh venv, torch first, then the timed `pip install SRC`; sizes and optional stacks present."""
    with tempfile.TemporaryDirectory(prefix="go-install-") as tmp:
        venv = Path(tmp) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        py = str(venv / "bin" / "python")
        pip = [py, "-m", "pip", "install", "--no-cache-dir", "-q"]
        subprocess.run([*pip, torch_spec], check=True)
        base_mb = _size_mb(venv)
        t0 = time.perf_counter()
        subprocess.run([*pip, str(src.resolve())], check=True)
        seconds = time.perf_counter() - t0
        total_mb = _size_mb(venv)
        site = next((venv / "lib").glob("python*/site-packages"))
        torch_mb = _size_mb(site / "torch")
        present = [m for m in OPTIONAL if (site / m).is_dir()]
        freeze = subprocess.run([py, "-m", "pip", "freeze"], check=True, capture_output=True, text=True)
    return {
        "install_s": round(seconds, 1),
        "venv_mb": round(total_mb, 1),
        "venv_without_torch_mb": round(total_mb - torch_mb, 1),
        "added_by_install_mb": round(total_mb - base_mb, 1),
        "packages": len(freeze.stdout.splitlines()),
        "optional_stacks_present": present,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("src", type=Path, help="the source tree to install")
    p.add_argument("--label", required=True, help="the key of this measurement in the JSON (before / after)")
    p.add_argument("--json", type=Path, default=Path("benchmarks/results/install_size.json"))
    args = p.parse_args(argv)
    facts = measure(args.src)
    facts["src"] = str(args.src)
    facts["python"] = sys.version.split()[0]
    data = json.loads(args.json.read_text()) if args.json.is_file() else {}
    data[args.label] = facts
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    print(json.dumps({args.label: facts}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
