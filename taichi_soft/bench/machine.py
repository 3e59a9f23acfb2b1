"""What machine a benchmark ran on: CPU model, cores, GPU, versions."""
from __future__ import annotations

import os
import platform
import subprocess


def cpu_model() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=5).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                return line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return platform.processor() or "unknown CPU"


def gpu_name() -> str | None:
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=5)
        if out.returncode == 0 and out.stdout.strip():
            return out.stdout.strip().splitlines()[0]
    except (OSError, subprocess.SubprocessError):
        pass
    return None


def describe() -> dict:
    import numpy
    import taichi

    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "gpu": gpu_name(),
        "python": platform.python_version(),
        "taichi": ".".join(map(str, taichi.__version__)),
        "numpy": numpy.__version__,
        "os": f"{platform.system()} {platform.release()}",
    }


def markdown(info: dict) -> str:
    gpu = info["gpu"] or "none"
    return (f"- CPU: {info['cpu']}, {info['cores']} cores; GPU: {gpu}\n"
            f"- Python {info['python']}, Taichi {info['taichi']}, numpy {info['numpy']}, {info['os']}\n")
