"""Issue 13's zero-config study: every MJCF robot through the whole chain with derived values only.

Run from the repository root:  python scripts/zero_config_study.py [MJCF ...]
(the same as ``python -m bemlearn bench robots``; see bemlearn/bench/robots_bench.py).
"""

import sys

from bemlearn.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["bench", "robots", *sys.argv[1:]]))
