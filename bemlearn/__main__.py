import sys

from bemlearn.cli.main import main

sys.exit(main())
