"""Packaging beyond what pyproject.toml can say: the Alembic migrations travel in the wheel.

The migration environment stays at the top of the repository (``alembic/``, used as is by
``alembic upgrade head`` from a clone) and is installed as ``app/migrations`` (no ``__init__.py``
on purpose: ``./alembic`` must never shadow the alembic library); ``app.jobs.database`` finds it there. The design page's files (``app/web/static``) travel as package data.
"""

from setuptools import find_packages, setup

setup(
    packages=find_packages(include=["solver", "solver.*", "app", "app.*"]) + ["app.migrations",
                                                                              "app.migrations.versions"],
    package_dir={"app.migrations": "alembic"},
    package_data={"app.migrations": ["script.py.mako"], "app.web": ["static/*"]},
)
