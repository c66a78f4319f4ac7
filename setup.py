"""Maps the repository's top-level folders onto the ``riskfield`` import namespace:
``protocol/`` → ``riskfield.protocol``, ``services/`` → ``riskfield.services``,
``edge/`` → ``riskfield.edge``. Everything else is in pyproject.toml."""

from setuptools import find_packages, setup

ROOTS = {
    "riskfield": "riskfield",
    "riskfield.protocol": "protocol",
    "riskfield.services": "services",
    "riskfield.edge": "edge",
}

packages: list[str] = []
for name, folder in ROOTS.items():
    packages.append(name)
    packages += [f"{name}.{sub}" for sub in find_packages(folder)]

setup(packages=packages, package_dir=ROOTS,
      package_data={"riskfield": ["py.typed"], "riskfield.services.safety_filter": ["presets/*.yaml"]})
