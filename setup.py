"""Package discovery; everything else is in pyproject.toml.

setuptools' ``packages.find`` in pyproject.toml cannot name a package after another folder, and the hydra
configs live at the repository root (``configs/``) but ship inside the package as ``dexmots_rl.configs``,
where the console scripts find them from an installed wheel. So the package list is found here: every
package under ``dexmots_rl/`` (a new task or asset folder ships without an edit) and every folder under
``configs/``, mapped to ``dexmots_rl.configs.*``.
"""

from setuptools import find_namespace_packages, setup

CONFIG_PACKAGES = find_namespace_packages(include=["configs", "configs.*"], exclude=["*.__pycache__"])

setup(
    packages=find_namespace_packages(include=["dexmots_rl", "dexmots_rl.*"], exclude=["*.__pycache__"])
    + [f"dexmots_rl.{name}" for name in CONFIG_PACKAGES],
    package_dir={f"dexmots_rl.{name}": name.replace(".", "/") for name in CONFIG_PACKAGES},
)
