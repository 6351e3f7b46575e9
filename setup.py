"""Packaging glue that pyproject.toml alone cannot express.

* ``steps/`` is installed as ``go_pipeline.steps`` (no generic top-level ``steps`` module in site-packages).
* ``pipeline.yaml`` and ``data_schema/`` live at the repository top level (the user's layout) and are copied
  into ``go_pipeline/_resources/`` of wheels; editable installs read them from the checkout.
"""

import shutil
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent


class BuildPyWithResources(build_py):
    def run(self) -> None:
        super().run()
        target = Path(self.build_lib) / "go_pipeline" / "_resources"
        target.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / "pipeline.yaml", target / "pipeline.yaml")
        shutil.copytree(ROOT / "data_schema", target / "data_schema", dirs_exist_ok=True)


packages = find_packages(include=["go_core", "go_core.*", "go_pipeline", "go_pipeline.*"])
steps = ["go_pipeline.steps"] + ["go_pipeline.steps." + p for p in find_packages("steps")]
package_dir = {"go_pipeline.steps": "steps"}

setup(packages=packages + steps, package_dir=package_dir, cmdclass={"build_py": BuildPyWithResources})
