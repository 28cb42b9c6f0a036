"""What the OpenCV comparison scripts share: the throwaway virtual environment they run OpenCV
in (the project itself never depends on Python), and where the shared footage is."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def ensure_venv(venv, packages):
    """The Python of `venv`, made with `packages` installed where it does not exist yet."""
    py = os.path.join(venv, "bin", "python")
    if not os.path.exists(py):
        subprocess.run([sys.executable, "-m", "venv", venv], check=True)
        subprocess.run([py, "-m", "pip", "install", "-q", *packages], check=True)
    return py


def default_data():
    """The shared footage: ../shared/data beside the repository, else /work/shared/data."""
    data = os.path.join(ROOT, "..", "shared", "data")
    return data if os.path.isdir(data) else "/work/shared/data"
