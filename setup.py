"""Ship the top-level protocols/, analysis/ and migrations/ folders inside the wheel.

They stay at the top of the repository, where coordinators and reviewers look for them, and are
mapped to ``studyctl._resources.*`` so an installed studyctl finds them without the source tree.
"""

from setuptools import find_namespace_packages, find_packages, setup

RESOURCE_DIRS = {"protocols": "protocols", "analysis": "analysis", "migrations": "migrations"}


def resource_packages() -> dict[str, str]:
    mapping = {}
    for name, folder in RESOURCE_DIRS.items():
        mapping[f"studyctl._resources.{name}"] = folder
        for sub in find_packages(where=folder) + [p for p in ("versions",) if name == "migrations"]:
            mapping[f"studyctl._resources.{name}.{sub}"] = f"{folder}/{sub.replace('.', '/')}"
    return mapping


mapped = resource_packages()
setup(
    # namespace packages too: data-only folders (studyctl/view/static, …) have no __init__.py
    packages=find_namespace_packages(include=["studyctl", "studyctl.*"], exclude=["*.__pycache__"]) + list(mapped),
    package_dir={"": ".", **mapped},
)
