"""Packaging hook: the wheel carries samp's config tree (`conf/` in the repository) as `samp/_conf/`.

The configs stay at the repository's top level, where the docs and the Hydra command lines name them;
`samp.paths.packaged_conf_dir` finds `samp/_conf/` in an installed wheel and `conf/` in a clone. An
editable install (`pip install -e .`) copies nothing: it reads the clone's `conf/` directly.
"""

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py


class BuildWithConfigs(build_py):
    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return
        source = Path(__file__).resolve().parent / "conf"
        target = Path(self.build_lib) / "samp" / "_conf"
        shutil.rmtree(target, ignore_errors=True)
        shutil.copytree(source, target, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", ".*"))


setup(cmdclass={"build_py": BuildWithConfigs})
