import sys

from gsgs_engine.cli import main

sys.exit(main())
