"""What pyproject.toml cannot say: the host firmware's C sources (firmware_sim/) ship inside the package as
`uwb_hil_firmware` (package data, a folder beside harness/), so an installed uwb-hil compiles its host
firmware on first use (harness/firmware_cache.py). Everything else is in pyproject.toml."""

from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["harness*", "protocol*"]), "uwb_hil_firmware"],
      package_dir={"uwb_hil_firmware": "firmware_sim"})
