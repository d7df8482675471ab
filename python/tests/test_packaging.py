"""The package builds as a wheel with its type marker and data files, so packaging cannot rot."""

import subprocess
import sys
import zipfile
from pathlib import Path


def test_the_wheel_builds_with_its_modules_and_type_marker(tmp_path):
    root = Path(__file__).resolve().parents[1]
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation", "-w", str(tmp_path), str(root)],
        check=True,
    )
    wheels = list(tmp_path.glob("nerf_bundle-*.whl"))
    assert len(wheels) == 1, wheels
    names = set(zipfile.ZipFile(wheels[0]).namelist())
    # march.cu: the GPU loop's kernels, read at run time.
    for module in ["__init__.py", "bundle.py", "cli.py", "py.typed", "_gpu.py", "march.cu"]:
        assert f"nerf_bundle/{module}" in names, sorted(names)
