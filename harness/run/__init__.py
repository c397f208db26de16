"""What `uwb-hil run` and `uwb-hil demo` do, as a library: the flight and configuration a run asks for
(source.py), one run or the resumption of one (single.py), the demo's flights (demo.py). The CLI
(harness/cli.py) only parses the options into these and prints what they return."""
