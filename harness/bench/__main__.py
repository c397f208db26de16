"""`python -m harness.bench`: the host part of `make bench` (harness/bench/host.py)."""

import sys

from harness.bench.host import main

if __name__ == "__main__":
    sys.exit(main())
