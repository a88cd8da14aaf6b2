"""`python -m clods_bench.cli`: the `clods-bench` command."""

import sys

from clods_bench.cli import main

sys.exit(main())
